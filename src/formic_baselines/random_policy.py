"""Random baseline: a uniformly random valid action (the floor of every comparison)."""

from __future__ import annotations

import numpy as np

from formic_agent.policy import AgentBatch, Policy


class RandomPolicy(Policy):
    name = "random"

    def __init__(self) -> None:
        self.rng = np.random.default_rng(0)

    def reset(self, n_agents: int, seed: int) -> None:
        self.rng = np.random.default_rng([seed, 11])

    def act(self, batch: AgentBatch) -> np.ndarray:
        mask = batch.action_mask.astype(float)
        # Agents with no valid action (queued, or boxed in) send NORTH, which is ignored or fails.
        mask[mask.sum(axis=1) == 0, 0] = 1.0
        cumulative = np.cumsum(mask / mask.sum(axis=1, keepdims=True), axis=1)
        draws = self.rng.random(len(batch))[:, None]
        return np.minimum((draws > cumulative).sum(axis=1), 4).astype(np.int64)
