"""The ForMIC actor-critic network (SPEC §5), batched over many agents.

conv3x3 x3 (c1) -> maxpool -> conv3x3 x3 (c2) -> maxpool -> conv to 1x1 (fc) -> ReLU = f;
f -> FC -> ReLU -> FC, + f, ReLU -> LSTM (rnn) -> policy logits (5) and value (1).
The valid-action predictor is sigmoid(logits): no extra layer.
"""

from __future__ import annotations

import torch
from torch import nn

from formic_world.geometry import N_ACTIONS

from .inputs import N_EXTRA_INPUTS, N_NEST_INPUTS, NetworkConfig


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
