"""Random baseline: a uniformly random valid action (the floor of every comparison)."""

from __future__ import annotations

import numpy as np

from formic_agent.policy import AgentBatch, Policy, agent_uniforms, sample_rows


class RandomPolicy(Policy):
    name = "random"

    def __init__(self) -> None:
        self.seed = 0

    def reset(self, n_agents: int, seed: int) -> None:
        self.seed = seed

    def act(self, batch: AgentBatch) -> np.ndarray:
        weights = batch.action_mask.astype(np.float64)
        # Agents with no valid action (queued, or boxed in) send NORTH, which is ignored or fails.
        weights[weights.sum(axis=1) == 0, 0] = 1.0
        return sample_rows(weights, agent_uniforms(self.seed, batch.step, batch.agent_ids, stream=11))
