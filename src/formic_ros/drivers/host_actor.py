""":class:`HostActor` is :class:`formic_trainer.actor.Actor` (the very actor ``formic train``
runs) over a learning host's agents, on the weights the trainer node broadcasts, reading the
frames ``formic train``'s worlds build (:func:`formic_trainer.worlds.make_frame`). No ROS node:
the learning host (:mod:`formic_ros.drivers.learning_host`) feeds it messages."""

from __future__ import annotations

import numpy as np
from formic_interfaces.msg import Weights

from formic_agent.checkpoint import CheckpointError, read_checkpoint
from formic_agent.inputs import ActionFeedback, NetworkConfig
from formic_agent.policy import AgentBatch
from formic_trainer.actor import Actor
from formic_trainer.algorithm import training_network
from formic_trainer.config import TrainConfig
from formic_trainer.rollout import Rollout
from formic_trainer.worlds import Frame, make_frame


def apply_weights(policy, msg: Weights) -> int:
    """Load a Weights message into a learned policy (or anything with its ``net`` and
    ``load_state_dict``; ``weights_only`` loading); returns its version."""
    payload = read_checkpoint(bytes(msg.data))
    config = NetworkConfig.from_dict(payload["network"])
    if config != policy.net.config:
        raise CheckpointError(f"weights for network {config} do not fit the policy's {policy.net.config}")
    policy.load_state_dict(payload["state_dict"])
    return int(msg.version)


class HostActor:
    """This host's agents as ``formic train``'s :class:`Actor` (its streams are seeded per
    episode). Per episode :meth:`start_episode`; per step :meth:`frame` (the world's
    observations as the actor reads them) and :meth:`outcome` (the chunk's Rollout once it is
    complete), then :meth:`act` on that frame once weights are loaded. ``first_episode``: the
    global number of the first episode (a resumed run's)."""

    def __init__(self, cfg: TrainConfig, agent_ids, first_episode: int = 0):
        self.cfg = cfg
        self.ids = np.asarray(sorted(agent_ids), dtype=np.int64)
        self.net = training_network(cfg)
        self.actor = Actor(cfg, self.net, self.ids, weights_version=-1)  # -1: no weights yet
        self.episode = first_episode - 1  # global episode number
        self.starting = False
        self.food = 0.0
        self.loads = np.zeros(len(self.ids))
        self.feedback = ActionFeedback()

    @property
    def version(self) -> int:
        """The weights version loaded (-1: none yet)."""
        return self.actor.weights_version

    def load_state_dict(self, state_dict: dict) -> None:
        self.net.load_state_dict(state_dict)

    def load_weights(self, msg: Weights) -> None:
        self.actor.weights_version = apply_weights(self, msg)

    def start_episode(self, loads: np.ndarray) -> None:
        self.episode += 1
        self.starting = True  # the actor starts it at its first action (it may wait for weights)
        self.food, self.loads = 0.0, np.asarray(loads, dtype=np.float64)
        self.feedback.reset(0)

    def frame(self, batch: AgentBatch, train_mask: np.ndarray, team_rewards: np.ndarray, rows: np.ndarray) -> Frame:
        """What this host's agents (``batch``: rows ``rows`` of the world's message) see."""
        return make_frame(self.cfg, batch, train_mask, self.feedback, team_rewards, rows)

    def act(self, batch: AgentBatch, frame: Frame) -> np.ndarray:
        """Actions for every agent of the batch (rows in id order); needs weights."""
        if self.starting:
            self.actor.start_episode(self.episode)
            self.starting = False
        actions = self.actor.act(frame)
        self.feedback.record(batch.agent_ids, actions, batch.positions, batch.queued)
        return actions

    def outcome(self, frame: Frame, loads: np.ndarray, done: bool) -> Rollout | None:
        """The frame after a step and the agents' loads in it; returns the chunk's Rollout when
        it is complete and any of these agents learns, else None."""
        self.actor.reward(frame.rewards)
        loads = np.asarray(loads, dtype=np.float64)
        self.food += float(np.clip(self.loads - loads, 0.0, None).sum())  # every agent's deliveries
        self.loads = loads
        if not done and len(self.actor) < self.cfg.rollout_steps:
            return None
        rollout = self.actor.rollout(frame, done, self.food)
        self.food = 0.0
        return rollout if len(self.actor.learning) else None
