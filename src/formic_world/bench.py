"""Core throughput: random valid actions, observations and masks included."""

from __future__ import annotations

import time

import numpy as np

from .config import WorldConfig
from .scenario import generate_scenario
from .world import World


def random_valid_actions(mask: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """One uniformly random valid action per row (action 0 where none is valid), vectorised."""
    weights = mask.astype(np.float64)
    weights[weights.sum(axis=1) == 0, 0] = 1.0
    cumulative = np.cumsum(weights, axis=1)
    draws = rng.random(len(mask)) * cumulative[:, -1]
    return (draws[:, None] >= cumulative).sum(axis=1)


def bench_world(size: int, agents: int, steps: int = 512, seed: int = 0) -> dict:
    config = WorldConfig(height=size, width=size, n_agents=agents, episode_steps=steps)
    world = World(generate_scenario(config, seed))
    rng = np.random.default_rng(seed)
    result = world.last_result
    start = time.perf_counter()
    while not world.done:
        result = world.step(random_valid_actions(result.action_mask, rng))
    seconds = time.perf_counter() - start
    return {
        "agents": agents,
        "steps": steps,
        "seconds": seconds,
        "steps_per_s": steps / seconds,
        "agent_steps_per_s": steps * agents / seconds,
    }
