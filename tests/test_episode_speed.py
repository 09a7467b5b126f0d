"""``formic sim``'s speed is measured as the ROS world node measures its own: steps after
step 0 by the wall clock, everything a step does included (benchmarks/transport_floor.py
compares the two)."""

from __future__ import annotations

from formic_runtime.episode import run_episode
from formic_world import WorldConfig, generate_scenario


def test_steps_per_s_counts_the_wall_clock_after_step_0():
    scenario = generate_scenario(WorldConfig(height=16, width=16, n_agents=4, episode_steps=12), seed=3)
    stats = run_episode(scenario, "random")
    start, end = stats.stepping
    assert stats.steps_per_s == 11 / (end - start)
    # the clock spans the decisions and world steps of steps 1-11 (timed inside), and more
    inside = stats.decision_seconds[1:].sum() + stats.step_seconds[1:].sum()
    assert end - start >= inside > 0
    assert stats.summary(scenario, "random")["steps_per_s"] == stats.steps_per_s


def test_a_one_step_episode_has_no_speed():
    scenario = generate_scenario(WorldConfig(height=16, width=16, n_agents=4, episode_steps=1), seed=3)
    assert run_episode(scenario, "random").steps_per_s == 0.0
