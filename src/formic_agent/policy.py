"""The one interface every decision maker implements: a batch of agents in, actions out.

``formic sim``, the evaluation harness and the ROS agent host all drive policies through
:class:`Policy`, so a learned network, a baseline rule and a user's own code are
interchangeable. Policies keep whatever per-agent memory they need, keyed by agent id, and
forget it in :meth:`Policy.reset` (new episode) or :meth:`Policy.forget` (an agent swapped in).
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from dataclasses import dataclass

import numpy as np


@dataclass
class AgentBatch:
    """What a group of agents senses at one step (rows indexed like ``agent_ids``)."""

    step: int
    agent_ids: np.ndarray  # (B,) int
    observations: np.ndarray  # (B, 8, V, V) float32, SPEC §3
    action_mask: np.ndarray  # (B, 5) bool, environment validity
    positions: np.ndarray  # (B, 2) int (row, col): odometry, used by rule-based baselines
    loads: np.ndarray  # (B,) float in [0, 1]
    queued: np.ndarray  # (B,) bool: the agent waits in a queue and its action is ignored
    world_shape: tuple[int, int]  # (H, W): the nest is at its centre

    def __len__(self) -> int:
        return len(self.agent_ids)

    def select(self, rows: np.ndarray) -> "AgentBatch":
        """These rows of the batch (one policy group's agents)."""
        return AgentBatch(
            step=self.step, agent_ids=self.agent_ids[rows], observations=self.observations[rows],
            action_mask=self.action_mask[rows], positions=self.positions[rows], loads=self.loads[rows],
            queued=self.queued[rows], world_shape=self.world_shape,
        )

    @classmethod
    def from_world(cls, world, agent_ids=None, observations=None, action_mask=None) -> "AgentBatch":
        """Everything a world gives its agents (optionally a subset), for in-process runs."""
        batch = cls(
            step=world.t, agent_ids=np.arange(world.config.n_agents),
            observations=world.observer.observe() if observations is None else observations,
            action_mask=world.action_mask() if action_mask is None else action_mask,
            positions=world.pos.copy(), loads=world.loads, queued=world.queued, world_shape=world.grid.shape,
        )
        return batch if agent_ids is None else batch.select(np.asarray(agent_ids))


def agent_uniforms(seed: int, step: int, agent_ids: np.ndarray, stream: int) -> np.ndarray:
    """One uniform draw per agent, keyed by (seed, step, agent id, stream).

    Sampling from these instead of a generator shared by the batch makes every agent's action
    independent of how agents are grouped into batches, processes or hosts, so a distributed
    run reproduces ``formic sim`` exactly.
    """
    ids = np.asarray(agent_ids, dtype=np.int64)
    if len(ids) == 0:
        return np.zeros(0)
    draws = np.random.default_rng([int(seed), int(step), int(stream)]).random(int(ids.max()) + 1)
    return draws[ids]


def sample_rows(probabilities: np.ndarray, uniforms: np.ndarray) -> np.ndarray:
    """Inverse-CDF sampling of one index per row."""
    cumulative = np.cumsum(probabilities, axis=1)
    cumulative /= cumulative[:, -1:]
    return np.minimum((uniforms[:, None] >= cumulative).sum(axis=1), probabilities.shape[1] - 1).astype(np.int64)


class Policy(ABC):
    """Observation batch in, action batch out."""

    name: str = "policy"
    # One memory for the whole team (marks on a shared ground): its agents must stay in one
    # process, so a distributed run does not split them across hosts.
    shares_team_memory: bool = False

    def reset(self, n_agents: int, seed: int) -> None:
        """Start of an episode: forget all memory; seed any randomness."""

    def wipe(self, steps: int | None = None) -> None:
        """A pheromone wipeout of ``steps`` steps (default: the policy's own) starts, called before
        that step's :meth:`act`: policies that keep marks of their own clear them here."""

    def forget(self, agent_ids: np.ndarray) -> None:
        """Forget the memory of these agents (one was swapped in mid-episode)."""

    @abstractmethod
    def act(self, batch: AgentBatch) -> np.ndarray:
        """Actions 0-4 for every row of the batch, shape (B,) int64."""


class CentralPolicy(ABC):
    """A policy that reads the full world state (the centralized planner)."""

    name: str = "central"
    shares_team_memory: bool = True

    def reset(self, n_agents: int, seed: int) -> None:
        """Start of an episode."""

    def wipe(self, steps: int | None = None) -> None:
        """A pheromone wipeout starts."""

    @abstractmethod
    def act_world(self, world) -> np.ndarray:
        """Actions for all agents of ``world``, shape (N,) int64."""
