"""The :class:`Rollout`: what an actor hands its learner, in one process (``formic train``) or as
the ROS message ``formic_interfaces/Rollout``, which carries it field for field under the same
names (``formic_ros.convert``). NumPy only, so the message codec needs no torch."""

from __future__ import annotations

from dataclasses import dataclass, fields

import numpy as np


@dataclass
class Rollout:
    """A chunk of T steps of an actor's A learning agents, arrays time-major, with what the actor
    computed while it acted (log-probabilities, values, the LSTM state it started from, the
    bootstrap value): the learner recomputes nothing, so PPO's ratio is taken against the very
    policy that acted, however many updates ago."""

    weights_version: int  # the weights that acted: the learner's updates when they were made
    episode: int  # global episode number
    done: bool  # the chunk ends its episode
    food: float  # food the agents' worlds deposited during the chunk
    agent_ids: np.ndarray  # (A,) int64, team-wide
    observations: np.ndarray  # (T+1, A, C, V, V) float32; the last frame is the bootstrap value's
    extra_inputs: np.ndarray  # (T+1, A, N_EXTRA_INPUTS) float32: odometry, own action feedback
    actions: np.ndarray  # (T, A) int64
    logprobs: np.ndarray  # (T, A) float32: of the actions, under the sampling mask
    values: np.ndarray  # (T, A) float32
    next_value: np.ndarray  # (A,) float32: of the last frame
    h0: np.ndarray  # (1, A, rnn) float32: the LSTM state before the first step
    c0: np.ndarray  # (1, A, rnn) float32
    rewards: np.ndarray  # (T, A) float32, unscaled
    train_mask: np.ndarray  # (T, A, 5) bool: the training filter's valid actions (the valid-action target)
    sample_mask: np.ndarray  # (T, A, 5) bool: what the agents could sample (the filter and its annealing)
    loss_mask: np.ndarray  # (T, A) bool: the agent was free (queued steps stay out of the losses)
    value_mask: np.ndarray  # (T, A) bool: False where the "replace" filter replaced the action
    expert_actions: np.ndarray | None = None  # (T, A) int64: the demonstrator's (imitation only)
    imitation_mask: np.ndarray | None = None  # (T, A) bool: which of them are targets

    @property
    def steps(self) -> int:
        return len(self.actions)


AGENT_AXIS = {"agent_ids": 0, "next_value": 0}  # the other arrays are time-major (agents on axis 1)


def join_rollouts(parts: list[Rollout]) -> Rollout:
    """One rollout of several actors' chunks of the same steps, agents in team-wide id order:
    the rollout one actor over all their agents would have made (``formic train`` makes one for
    all its worlds). Scalars: the oldest weights and episode, done when any part is done, the
    food summed."""
    parts = sorted(parts, key=lambda part: int(part.agent_ids[0]))
    arrays = {}
    for field in fields(Rollout):
        values = [getattr(part, field.name) for part in parts]
        if isinstance(values[0], np.ndarray):
            arrays[field.name] = np.concatenate(values, axis=AGENT_AXIS.get(field.name, 1))
    return Rollout(weights_version=min(p.weights_version for p in parts), episode=min(p.episode for p in parts),
                   done=any(p.done for p in parts), food=float(sum(p.food for p in parts)), **arrays)
