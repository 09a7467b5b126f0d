"""What the network reads, without torch: its configuration (:class:`NetworkConfig` and the
presets) and the inputs a frame carries beside the observation (odometry, action feedback).

A world in training mode and the frame builders need these; keeping them apart from
:mod:`formic_agent.network` keeps torch out of the processes that never run a network.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np

from formic_world.geometry import N_ACTIONS, nest_centre
from formic_world.limits import MAX_NETWORK_WIDTH, MAX_VIEW_SIZE, check_at_most


@dataclass(frozen=True)
class NetworkConfig:
    conv1: int = 128
    conv2: int = 256
    fc: int = 512
    rnn: int = 512
    view_size: int = 11
    channels: int = 8
    # Opt-in extension (never in the paper configuration): odometry to the nest and own load.
    nest_input: bool = False
    # Opt-in switch (issue 11's lever; tells nothing of the nest): the agent's own previous
    # action and whether it took effect, so the LSTM can integrate its moves in a crowd.
    action_input: bool = False

    def __post_init__(self) -> None:
        """Refuse widths a checkpoint could ask for before any layer is allocated."""
        for name in ("conv1", "conv2", "fc", "rnn", "channels"):
            width = getattr(self, name)
            if not isinstance(width, int) or width < 1:
                raise ValueError(f"network {name} must be a positive integer, got {width!r}")
            check_at_most(f"network {name}", width, MAX_NETWORK_WIDTH)
        check_at_most("network view_size", self.view_size, MAX_VIEW_SIZE)

    @property
    def reads_extra(self) -> bool:
        """Whether the network reads any input beside the observation."""
        return self.nest_input or self.action_input

    def to_dict(self) -> dict:
        return dataclasses.asdict(self)

    @classmethod
    def from_dict(cls, data: dict) -> NetworkConfig:
        known = {f.name for f in dataclasses.fields(cls)}
        unknown = set(data) - known
        if unknown:
            raise ValueError(f"unknown network configuration keys: {sorted(unknown)}")
        return cls(**data)


NETWORK_PRESETS = {
    "paper": NetworkConfig(),
    "cpu": NetworkConfig(conv1=16, conv2=32, fc=64, rnn=64),
    "cpu-nest": NetworkConfig(conv1=16, conv2=32, fc=64, rnn=64, nest_input=True),
    "cpu-feedback": NetworkConfig(conv1=16, conv2=32, fc=64, rnn=64, action_input=True),
}
# Every frame carries all extra inputs, in this layout; a network reads the blocks it is set for.
N_NEST_INPUTS = 4  # unit vector to the nest (2), distance to it / 32, own load
N_FEEDBACK_INPUTS = N_ACTIONS + 1  # previous action one-hot (5), whether it took effect
N_EXTRA_INPUTS = N_NEST_INPUTS + N_FEEDBACK_INPUTS


def nest_features(positions: np.ndarray, loads: np.ndarray, world_shape: tuple[int, int]) -> np.ndarray:
    """The opt-in odometry input (N, 4) float32: the direction to the nest centre as a unit
    vector, the distance in units of 32 cells, and the agent's load. Kept at unit scale: raw
    offsets divided by the world size are tiny near the nest, and the network then learned
    homing far more slowly (measured)."""
    offset = np.asarray(nest_centre(*world_shape)) - positions
    distance = np.linalg.norm(offset, axis=1, keepdims=True)
    return np.concatenate([offset / distance, distance / 32.0, loads[:, None]], axis=1).astype(np.float32)


class ActionFeedback:
    """Each agent's own previous action and whether it took effect (moved, or joined a queue),
    from what the agent itself knows: the action it sent and its position and queue state
    before and after. Zeros before an agent's first action, after :meth:`forget`, and when its
    last action was ignored (queued) or missing. Memory is keyed by agent id."""

    def __init__(self, n_agents: int = 0):
        self.reset(n_agents)

    def reset(self, n_agents: int) -> None:
        self.action = np.full(n_agents, -1, dtype=np.int64)
        self.position = np.zeros((n_agents, 2), dtype=np.int64)
        self.queued = np.zeros(n_agents, dtype=bool)

    def forget(self, agent_ids: np.ndarray) -> None:
        ids = np.asarray(agent_ids, dtype=np.int64)
        self._ensure_capacity(ids)
        self.action[ids] = -1

    def _ensure_capacity(self, agent_ids: np.ndarray) -> None:
        grow = int(agent_ids.max(initial=-1)) + 1 - len(self.action)
        if grow > 0:
            self.action = np.concatenate([self.action, np.full(grow, -1, dtype=np.int64)])
            self.position = np.concatenate([self.position, np.zeros((grow, 2), dtype=np.int64)])
            self.queued = np.concatenate([self.queued, np.zeros(grow, dtype=bool)])

    def features(self, agent_ids: np.ndarray, positions: np.ndarray, queued: np.ndarray) -> np.ndarray:
        """(B, N_FEEDBACK_INPUTS) float32 for these agents now (no side effect)."""
        ids = np.asarray(agent_ids, dtype=np.int64)
        self._ensure_capacity(ids)
        action = self.action[ids]
        acted = (action >= 0) & ~self.queued[ids]
        took_effect = (np.asarray(positions) != self.position[ids]).any(axis=1) | np.asarray(queued, dtype=bool)
        out = np.zeros((len(ids), N_FEEDBACK_INPUTS), dtype=np.float32)
        rows = np.flatnonzero(acted)
        out[rows, action[rows]] = 1.0
        out[rows, N_ACTIONS] = took_effect[rows]
        return out

    def record(self, agent_ids: np.ndarray, actions: np.ndarray, positions: np.ndarray, queued: np.ndarray) -> None:
        """The actions these agents send now, from these positions and queue states."""
        ids = np.asarray(agent_ids, dtype=np.int64)
        self._ensure_capacity(ids)
        self.action[ids] = actions
        self.position[ids] = positions
        self.queued[ids] = queued


def extra_inputs(nest: np.ndarray, feedback: np.ndarray) -> np.ndarray:
    """One frame's extra inputs (B, N_EXTRA_INPUTS) from its blocks, in the fixed layout."""
    return np.concatenate([nest, feedback], axis=1).astype(np.float32, copy=False)
