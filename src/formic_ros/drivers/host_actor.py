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
from formic_trainer.actor import Actor, step_food
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


class HostActor(Actor):
    """``formic train``'s :class:`Actor` over this host's agents (its streams seeded per global
    episode, from ``first_episode``: a resumed run's), plus what the world's meta-agents keep
    for them in one process: the agents' action feedback and the food their steps deposit,
    summed over the episode as :func:`formic_trainer.train.play_episode_set` sums it (a chunk's
    food: the sum at its end less the sum at its start). Per episode :meth:`begin`; per step
    :meth:`frame`, then :meth:`outcome` (the chunk's Rollout once it is complete) and
    :meth:`act_on` that frame once weights are loaded."""

    def __init__(self, cfg: TrainConfig, agent_ids, first_episode: int = 0):
        super().__init__(cfg, training_network(cfg), sorted(agent_ids), weights_version=-1)  # -1: no weights yet
        self.next_episode = first_episode
        self.feedback = ActionFeedback()
        self.load_full, self.loads = 1, np.zeros(len(self.ids))
        self.food = self.chunk_food_start = 0.0  # the episode's food so far, and at the chunk's start

    def load_state_dict(self, state_dict: dict) -> None:
        self.net.load_state_dict(state_dict)

    def load_weights(self, msg: Weights) -> None:
        self.weights_version = apply_weights(self, msg)

    def begin(self, batch: AgentBatch, load_full: int) -> None:
        """The next episode starts with ``batch`` (its step 0), in a world whose full load is
        ``load_full`` ticks."""
        self.start_episode(self.next_episode)
        self.next_episode += len(self.cfg.teams)  # an episode set counts one episode per world, as in formic train
        self.feedback.reset(0)
        self.load_full, self.loads = load_full, batch.loads
        self.food = self.chunk_food_start = 0.0

    def frame(self, batch: AgentBatch, train_mask: np.ndarray, team_rewards: np.ndarray, rows: np.ndarray) -> Frame:
        """What this host's agents (``batch``: rows ``rows`` of the world's message) see."""
        return make_frame(self.cfg, batch, train_mask, self.feedback, team_rewards, rows)

    def act_on(self, batch: AgentBatch, frame: Frame) -> np.ndarray:
        """Actions for every agent of the batch (rows in id order); needs weights."""
        actions = self.act(frame)
        self.feedback.record(batch.agent_ids, actions, batch.positions, batch.queued)
        return actions

    def outcome(self, frame: Frame, loads: np.ndarray, done: bool) -> Rollout | None:
        """The frame after a step and the agents' loads in it; returns the chunk's Rollout when
        it is complete and any of these agents learns, else None."""
        self.reward(frame.rewards)
        self.food += step_food(self.loads, loads, self.load_full)
        self.loads = loads
        if not done and len(self) < self.cfg.rollout_steps:
            return None
        rollout = self.rollout(frame, done, self.food - self.chunk_food_start)
        self.chunk_food_start = self.food
        return rollout if len(self.learning) else None
