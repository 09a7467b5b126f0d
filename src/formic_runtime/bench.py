"""``formic bench decide``: in-process decision time per step, the way ``formic sim`` runs."""

from __future__ import annotations

from formic_world import WorldConfig, generate_scenario

from .episode import run_episode
from .threads import configure_threads


def bench_decide(size: int, team_sizes: list[int], steps: int, seed: int, policy: str = "formic",
                 model: str | None = None, threads: int = 1) -> list[dict]:
    """Mean wall time the team takes to choose its actions per step (step 0, which warms
    caches up, left out) and of the world step, for each team size. ``threads=0`` leaves
    torch's default thread pool (to compare)."""
    if threads:
        configure_threads(threads)
    results = []
    for n in team_sizes:
        config = WorldConfig(height=size, width=size, n_agents=n, episode_steps=steps)
        stats = run_episode(generate_scenario(config, seed), policy, model=model)
        results.append({
            "agents": n,
            "decide_ms_per_step": float(stats.decision_seconds[1:].mean() * 1e3),
            "world_ms_per_step": float(stats.step_seconds[1:].mean() * 1e3),
        })
    return results
