"""One episode in one process: a world driven by a team of policies, and the per-step
bookkeeping (:class:`EpisodeStats`) every runner keeps: ``formic sim``, the evaluation harness
and the ROS world node, whose summaries therefore read alike."""

from __future__ import annotations

import time
from typing import Callable

import numpy as np

from formic_agent.policy import AgentBatch
from formic_world import Scenario, World

from .registry import apply_world_overrides
from .team import Team


class EpisodeStats:
    """What each step of an episode did: food over time, per-agent work, timings."""

    def __init__(self, n_agents: int, horizon: int):
        self.food_curve = np.zeros(horizon)  # cumulative food after each step
        self.collected, self.delivered = np.zeros(n_agents), np.zeros(n_agents)  # units per agent
        self.moves = np.zeros(n_agents, dtype=np.int64)  # steps each agent spent free
        self.queued_steps = np.zeros(n_agents, dtype=np.int64)  # steps each agent spent queued
        self.decision_seconds = np.zeros(horizon)  # wall time the team took to choose actions
        self.step_seconds = np.zeros(horizon)  # wall time of the world step
        self.food = 0.0
        self.world: World | None = None
        self.stepping = (0.0, 0.0)  # wall clock (perf_counter s) at the end of step 0 and of the last step

    @property
    def steps_per_s(self) -> float:
        """Steps after step 0 per wall-clock second, everything a step does included (as the
        ROS world node measures it: start-up and the first step's warm-up excluded)."""
        start, end = self.stepping
        return (len(self.food_curve) - 1) / (end - start) if end > start else 0.0

    def record(self, t: int, world: World, loads_before: np.ndarray, queued_before: np.ndarray,
               decision_s: float, step_s: float) -> None:
        """Step ``t`` (``world`` after it; loads and queue flags from before it)."""
        change = world.loads - loads_before
        self.collected += np.clip(change, 0, None)
        self.delivered += np.clip(-change, 0, None)
        self.queued_steps += queued_before
        self.moves += ~queued_before
        self.food_curve[t] = self.food = world.score
        self.decision_seconds[t], self.step_seconds[t] = decision_s, step_s
        self.world = world

    @property
    def step_ms_mean(self) -> float:
        return float(self.decision_seconds.mean() * 1e3)

    def summary(self, scenario: Scenario, policy: str | Team) -> dict:
        """The episode's summary (``formic sim --json``; ``formic run`` adds its own keys)."""
        cfg = scenario.config
        curve = self.food_curve
        marks = sorted({min(len(curve), m) for m in (64, 128, 256, 384, 512, 768, 1024, len(curve))})
        return {
            "policy": policy if isinstance(policy, str) else policy.describe(),
            "seed": scenario.seed,
            "size": [cfg.height, cfg.width],
            "agents": cfg.n_agents,
            "resources": len(scenario.resources),
            "steps": len(curve),
            "food": float(self.food),
            "food_over_time": {str(m): float(curve[m - 1]) for m in marks if m > 0},
            "per_agent": {
                "collected": self.collected.round(3).tolist(),
                "delivered": self.delivered.round(3).tolist(),
                "queued_steps": self.queued_steps.tolist(),
            },
            "step_ms_mean": self.step_ms_mean,
            "world_step_ms_mean": float(self.step_seconds.mean() * 1e3),
            "steps_per_s": self.steps_per_s,
            "state_digest": self.world.state_digest(),
        }


def run_episode(
    scenario: Scenario,
    policy: str | Team = "random",
    model: str | None = None,
    greedy: bool = False,
    steps: int | None = None,
    on_step: Callable[[World], None] | None = None,
) -> EpisodeStats:
    """Run ``scenario`` to its end (or ``steps``) with a team (a spec, or a :class:`Team`,
    built here unless it already is), in the world the team's policies need
    (registry.POLICY_WORLD_OVERRIDES; ``result.world.scenario`` is the scenario that ran)."""
    team = Team.parse(policy, scenario.config.n_agents) if isinstance(policy, str) else policy
    scenario = apply_world_overrides(scenario, team.names)
    if not team.members:
        team.build(model=model, greedy=greedy)
    cfg = scenario.config
    team.reset(cfg.n_agents, scenario.seed)
    world = World(scenario)
    result = world.last_result
    horizon = min(steps or cfg.episode_steps, cfg.episode_steps)
    stats = EpisodeStats(cfg.n_agents, horizon)
    stats.world = world
    wipe_starts = set(scenario.wipeout_starts)
    stepping_from = 0.0
    for t in range(horizon):
        if t in wipe_starts:
            team.wipe()
        t0 = time.perf_counter()
        batch = AgentBatch.from_world(world, observations=result.observations, action_mask=result.action_mask)
        actions = team.act(batch, world)
        t1 = time.perf_counter()
        queued, before = world.queued.copy(), world.loads.copy()
        result = world.step(actions)
        stats.record(t, world, before, queued, t1 - t0, time.perf_counter() - t1)
        if on_step is not None:
            on_step(world)
        if t == 0:
            stepping_from = time.perf_counter()
    stats.stepping = (stepping_from, time.perf_counter())
    return stats
