"""The ForMIC actor-critic network (SPEC §5), batched over many agents.

conv3x3 x3 (c1) -> maxpool -> conv3x3 x3 (c2) -> maxpool -> conv to 1x1 (fc) -> ReLU = f;
f -> FC -> ReLU -> FC, + f, ReLU -> LSTM (rnn) -> policy logits (5) and value (1).
The valid-action predictor is sigmoid(logits): no extra layer.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np
import torch
from torch import nn

from formic_world.geometry import N_ACTIONS, nest_centre


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


def _conv_block(c_in: int, c_out: int) -> list[nn.Module]:
    layers: list[nn.Module] = []
    for i in range(3):
        layers += [nn.Conv2d(c_in if i == 0 else c_out, c_out, 3, padding=1), nn.ReLU()]
    return layers


class ForMICNet(nn.Module):
    def __init__(self, config: NetworkConfig):
        super().__init__()
        self.config = config
        spatial = config.view_size // 2 // 2  # after two 2x2 max-pools (11 -> 5 -> 2)
        if spatial < 1:
            raise ValueError(f"view size {config.view_size} is too small for two poolings")
        self.encoder = nn.Sequential(
            *_conv_block(config.channels, config.conv1),
            nn.MaxPool2d(2),
            *_conv_block(config.conv1, config.conv2),
            nn.MaxPool2d(2),
            nn.Conv2d(config.conv2, config.fc, spatial),  # to 1x1
            nn.Flatten(),
            nn.ReLU(),
        )
        self.fc1 = nn.Linear(config.fc + len(self.extra_columns()), config.fc)
        self.fc2 = nn.Linear(config.fc, config.fc)
        self.lstm = nn.LSTM(config.fc, config.rnn)
        self.policy_head = nn.Linear(config.rnn, N_ACTIONS)
        self.value_head = nn.Linear(config.rnn, 1)
        nn.init.orthogonal_(self.policy_head.weight, 0.01)
        nn.init.zeros_(self.policy_head.bias)

    def extra_columns(self) -> list[int]:
        """The columns of the extra inputs this network reads (after f in fc1's input)."""
        columns = list(range(N_NEST_INPUTS)) if self.config.nest_input else []
        if self.config.action_input:
            columns += list(range(N_NEST_INPUTS, N_EXTRA_INPUTS))
        return columns

    def initial_state(self, batch: int) -> tuple[torch.Tensor, torch.Tensor]:
        zeros = torch.zeros(1, batch, self.config.rnn)
        return zeros, zeros.clone()

    def encode(self, obs: torch.Tensor) -> torch.Tensor:
        """The encoder's output f (B, fc) for obs (B, 8, V, V).

        Without gradients (acting, evaluation) the convolutions run on oneDNN's blocked layout
        (the input converted once, the layers unchanged): 1.3-1.6x faster than the eager
        channels-last path at 352 frames on one thread, and the same bits for any batch size and
        thread count (docs/training.md, "Where training time goes"). The values differ from the
        eager path's by rounding only (~1e-8). With gradients (the PPO update) the eager path
        runs: autograd through the blocked layout is no faster (measured)."""
        if torch.is_grad_enabled() or not torch.backends.mkldnn.is_available():
            return self.encoder(obs)
        *convolutions, flatten, relu = self.encoder
        x = obs.contiguous().to_mkldnn()
        for layer in convolutions:
            x = layer(x)
        return relu(flatten(x.to_dense()))

    def features(self, obs: torch.Tensor, extra: torch.Tensor | None) -> torch.Tensor:
        """Per-frame features before the LSTM; obs (B, 8, V, V)."""
        f = self.encode(obs)
        columns = self.extra_columns()
        if columns and extra is None:
            raise ValueError("this network reads extra inputs and none were given")
        x = torch.cat([f, extra[:, columns]], dim=1) if columns else f
        return torch.relu(self.fc2(torch.relu(self.fc1(x))) + f)

    def forward(
        self,
        obs: torch.Tensor,
        state: tuple[torch.Tensor, torch.Tensor],
        extra: torch.Tensor | None = None,
    ) -> tuple[torch.Tensor, torch.Tensor, tuple[torch.Tensor, torch.Tensor]]:
        """obs (T, B, 8, V, V) -> logits (T, B, 5), values (T, B), new state."""
        steps, batch = obs.shape[:2]
        flat_extra = None if extra is None else extra.reshape(steps * batch, -1)
        x = self.features(obs.reshape(steps * batch, *obs.shape[2:]), flat_extra)
        out, new_state = self.lstm(x.reshape(steps, batch, -1), state)
        return self.policy_head(out), self.value_head(out).squeeze(-1), new_state


def count_parameters(net: nn.Module) -> int:
    return sum(p.numel() for p in net.parameters())
