"""Pheromone rules that are not the per-step deposit loop (SPEC §2).

Deposits themselves happen inside the step (``kernels.act_agents``: P[c] <- max(P[c], v),
then p <- alpha * p); decay and wipeouts are in ``World.step``. This module holds what
varies by variant, the training highways and the curriculum schedule.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from .config import WorldConfig
from .geometry import DIRECTION_DELTAS, FREE

if TYPE_CHECKING:
    from .world import World


def deposit_values(config: WorldConfig, rng: np.random.Generator, n_agents: int) -> np.ndarray:
    """Per-agent deposit factor for this step; the kernel multiplies it by the agent's p.

    ``standard``/``flat``: the strength I_c. ``noisy``: I_c * U[0.8, 1.2] (the kernel clips
    to 1). ``random``: I_c * U[0.2, 1] used as the whole value (no intensity, no gradient).
    """
    variant = config.pheromone_variant
    if variant == "noisy":
        return config.deposit_strength * rng.uniform(0.8, 1.2, size=n_agents)
    if variant == "random":
        return config.deposit_strength * rng.uniform(0.2, 1.0, size=n_agents)
    return np.full(n_agents, config.deposit_strength)


def greedy_path(
    passable: np.ndarray, start: tuple[int, int], goal: tuple[int, int]
) -> list[tuple[int, int]] | None:
    """Walk from start to goal, each step to the unvisited passable neighbour best aligned
    with the straight line to the goal (ties: N, E, S, W). None if the walk gets stuck."""
    height, width = passable.shape
    path = [start]
    visited = {start}
    for _ in range(4 * (height + width)):
        current = path[-1]
        if current == goal:
            return path
        to_goal = np.array([goal[0] - current[0], goal[1] - current[1]], dtype=float)
        to_goal /= np.linalg.norm(to_goal)
        best, best_score = None, -np.inf
        for delta in DIRECTION_DELTAS:
            nxt = (current[0] + int(delta[0]), current[1] + int(delta[1]))
            if not (0 <= nxt[0] < height and 0 <= nxt[1] < width) or nxt in visited or not passable[nxt]:
                continue
            score = float(delta @ to_goal)
            if score > best_score:
                best, best_score = nxt, score
        if best is None:
            return None
        path.append(best)
        visited.add(best)
    return None


def highway_map(world: "World") -> np.ndarray:
    """Static training highways: per resource, the trail a loaded agent walking the greedy
    path to the nearest cache queue would leave. Cell k of an n-cell path (k=0 at the
    resource end) holds alpha^k * beta^(n-1-k); paths combine by max. Walks that get stuck
    (possible among obstacles) leave no highway."""
    cfg = world.config
    alpha, beta = cfg.effective_alpha, cfg.beta
    highways = np.zeros(world.grid.shape, dtype=np.float64)
    passable = world.grid == FREE
    cache_spots = [tuple(int(v) for v in world.queue_cells[q, 0]) for q in range(4)]
    for q in range(4, len(world.queue_cells)):
        start = tuple(int(v) for v in world.queue_cells[q, 0])
        goal = min(cache_spots, key=lambda s: (abs(s[0] - start[0]) + abs(s[1] - start[1]), s))
        path = greedy_path(passable, start, goal)
        if path is None:
            continue
        n = len(path)
        k = np.arange(n)
        values = alpha**k * beta ** (n - 1 - k)
        rows, cols = np.array(path).T
        highways[rows, cols] = np.maximum(highways[rows, cols], values)
    return highways


def curriculum_intensities(episode: int, start: int = 5000, end: int = 10000) -> tuple[float, float]:
    """(I_h, I_c) for a global training episode: highways fade out as agent deposits fade in."""
    if episode < start:
        return 1.0, 0.0
    if episode >= end:
        return 0.0, 1.0
    deposit = (episode - start) / (end - start)
    return 1.0 - deposit, deposit
