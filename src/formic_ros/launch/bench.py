"""``formic bench ros``: lockstep steps/s of a world process and one agent host process over
ROS, with the random policy, so the number is the cost of messaging (plus the core's step)."""

from __future__ import annotations

from formic_world import WorldConfig, generate_scenario

from .launcher import RunOptions, launch


def bench_ros(agents: int, transport: str, steps: int = 300, size: int = 64, repeats: int = 1,
              domain_id: int | None = None) -> dict:
    """Best of ``repeats`` launches: steps/s after step 0 (start-up and discovery excluded)."""
    scenario = generate_scenario(WorldConfig(height=size, width=size, n_agents=agents, episode_steps=steps), seed=0)
    options = RunOptions(scenario=scenario, policy="random", transport=transport, domain_id=domain_id,
                         deadline_ms=5000.0, timeout_s=300.0)
    runs = [launch(options) for _ in range(repeats)]
    best = max(runs, key=lambda s: s["steps_per_s"])
    kept = {"steps_per_s": "steps_per_s", "world_step_ms": "world_step_ms_mean",  # ours: the summary's
            "world_cpu_ms_per_step": "world_cpu_ms_per_step", "missed_actions": "missed_actions",
            "startup_s": "startup_s"}
    return {"agents": agents, "transport": transport, **{key: best[field] for key, field in kept.items()}}
