"""The learned ForMIC policy: one network, batched over every agent it drives, with an
LSTM state per agent id."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import torch

from .checkpoint import load_network
from .inputs import ActionFeedback, extra_inputs, nest_features
from .network import ForMICNet
from .policy import AgentBatch, Policy, agent_uniforms, sample_rows


class LearnedPolicy(Policy):
    name = "formic"

    def __init__(self, net: ForMICNet, greedy: bool = False, checkpoint: str = ""):
        self.net = net.eval()
        self.greedy = greedy
        self.checkpoint = checkpoint
        self.reset(0, 0)

    @classmethod
    def from_checkpoint(cls, path: str | Path, greedy: bool = False) -> "LearnedPolicy":
        net, _ = load_network(path)
        return cls(net, greedy=greedy, checkpoint=str(path))

    def load_state_dict(self, state_dict: dict) -> None:
        """Swap weights (the trainer broadcasts new ones between episodes)."""
        self.net.load_state_dict(state_dict)

    def reset(self, n_agents: int, seed: int) -> None:
        self.seed = int(seed)
        self.hidden = torch.zeros(1, n_agents, self.net.config.rnn)
        self.cell = torch.zeros(1, n_agents, self.net.config.rnn)
        self.feedback = ActionFeedback(n_agents)

    def forget(self, agent_ids: np.ndarray) -> None:
        self.hidden[:, agent_ids] = 0.0
        self.cell[:, agent_ids] = 0.0
        self.feedback.forget(agent_ids)

    def _ensure_capacity(self, max_id: int) -> None:
        if max_id >= self.hidden.shape[1]:
            grow = max_id + 1 - self.hidden.shape[1]
            pad = torch.zeros(1, grow, self.net.config.rnn)
            self.hidden = torch.cat([self.hidden, pad], dim=1)
            self.cell = torch.cat([self.cell, pad.clone()], dim=1)

    @property
    def view_size(self) -> int:
        """The observation window this network was trained on (the world must give it)."""
        return self.net.config.view_size

    @torch.no_grad()
    def act(self, batch: AgentBatch) -> np.ndarray:
        seen = batch.observations.shape[-1]
        if seen != self.view_size:
            raise ValueError(f"{self.checkpoint or 'this model'} sees {self.view_size}x{self.view_size} cells, the "
                             f"world gives {seen}x{seen}: run the world with --view-size {self.view_size}")
        ids = torch.as_tensor(batch.agent_ids, dtype=torch.long)
        self._ensure_capacity(int(ids.max()))
        obs = torch.from_numpy(batch.observations).unsqueeze(0)
        extra = extra_inputs(nest_features(batch.positions, batch.loads, batch.world_shape),
                             self.feedback.features(batch.agent_ids, batch.positions, batch.queued))
        state = (self.hidden[:, ids], self.cell[:, ids])
        logits, _, (h, c) = self.net(obs, state, torch.from_numpy(extra).unsqueeze(0))
        self.hidden[:, ids], self.cell[:, ids] = h, c
        logits = logits[0]
        if self.greedy:
            actions = logits.argmax(dim=1).numpy().astype(np.int64)
        else:
            probabilities = torch.softmax(logits.double(), dim=1).numpy()
            actions = sample_rows(probabilities, agent_uniforms(self.seed, batch.step, batch.agent_ids, stream=13))
        self.feedback.record(batch.agent_ids, actions, batch.positions, batch.queued)
        return actions
