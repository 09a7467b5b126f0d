"""One episode in one process: a world driven by a team of policies.

Used by ``formic sim`` and the evaluation harness; the ROS system runs the same world and
the same policies across processes and must reproduce these numbers.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from typing import Callable

import numpy as np

from formic_world import Scenario, World

from .policy import AgentBatch, CentralPolicy, Policy
from .registry import TeamAssignment, apply_world_overrides, make_policy, parse_team


@dataclass
class EpisodeResult:
    food: float
    food_curve: np.ndarray  # (T,) cumulative food after each step
    collected: np.ndarray  # (N,) units gathered per agent
    delivered: np.ndarray  # (N,) units unloaded at the nest per agent
    moves: np.ndarray  # (N,) steps each agent spent free (moving or trying)
    queued_steps: np.ndarray  # (N,) steps each agent spent in a queue
    decision_seconds: np.ndarray  # (T,) wall time the whole team took to choose actions
    step_seconds: np.ndarray  # (T,) wall time of the world step
    digests: list[str] = field(default_factory=list)
    world: World | None = None

    @property
    def step_ms_mean(self) -> float:
        return float(self.decision_seconds.mean() * 1e3)


def build_team(team: TeamAssignment, model: str | None = None, greedy: bool = False) -> list[tuple[Policy | CentralPolicy, np.ndarray]]:
    return [(make_policy(name, model=model, greedy=greedy), np.array(ids)) for name, ids in team.groups]


def run_episode(
    scenario: Scenario,
    policy: str | TeamAssignment = "random",
    model: str | None = None,
    greedy: bool = False,
    steps: int | None = None,
    policies: list[tuple[Policy | CentralPolicy, np.ndarray]] | None = None,
    on_step: Callable[[World], None] | None = None,
    record_digests: bool = False,
) -> EpisodeResult:
    """Run ``scenario`` to its end (or ``steps``) with the given team of policies, in the world
    the team's policies need (registry.POLICY_WORLD_OVERRIDES; ``result.world.scenario`` is the
    scenario that ran)."""
    team = parse_team(policy, scenario.config.n_agents) if isinstance(policy, str) else policy
    scenario = apply_world_overrides(scenario, [name for name, _ in team.groups])
    cfg = scenario.config
    n = cfg.n_agents
    members = policies if policies is not None else build_team(team, model=model, greedy=greedy)
    for p, _ in members:
        p.reset(n, scenario.seed)
    world = World(scenario)
    result = world.reset(scenario)
    horizon = min(steps or cfg.episode_steps, cfg.episode_steps)
    food_curve = np.zeros(horizon)
    collected, delivered = np.zeros(n), np.zeros(n)
    moves, queued_steps = np.zeros(n, dtype=np.int64), np.zeros(n, dtype=np.int64)
    decision_s, step_s = np.zeros(horizon), np.zeros(horizon)
    digests: list[str] = []
    wipe_starts = set(scenario.wipeout_starts)
    actions = np.zeros(n, dtype=np.int64)
    for t in range(horizon):
        if t in wipe_starts:
            for p, _ in members:
                if getattr(p, "uses_world_wipeouts", False):
                    p.wipe()
        t0 = time.perf_counter()
        batch = AgentBatch.from_world(world, observations=result.observations, action_mask=result.action_mask)
        for p, ids in members:
            if isinstance(p, CentralPolicy):
                actions[:] = p.act_world(world)
            else:
                sub = _subset(batch, ids)
                actions[ids] = p.act(sub)
        t1 = time.perf_counter()
        queued = world.queued.copy()
        before = world.loads.copy()
        result = world.step(actions)
        step_s[t] = time.perf_counter() - t1
        decision_s[t] = t1 - t0
        change = world.loads - before
        collected += np.clip(change, 0, None)
        delivered += np.clip(-change, 0, None)
        queued_steps += queued
        moves += ~queued
        food_curve[t] = world.score
        if record_digests:
            digests.append(world.state_digest())
        if on_step is not None:
            on_step(world)
    return EpisodeResult(
        food=world.score,
        food_curve=food_curve,
        collected=collected,
        delivered=delivered,
        moves=moves,
        queued_steps=queued_steps,
        decision_seconds=decision_s,
        step_seconds=step_s,
        digests=digests,
        world=world,
    )


def _subset(batch: AgentBatch, ids: np.ndarray) -> AgentBatch:
    if len(ids) == len(batch.agent_ids):
        return batch
    return AgentBatch(
        step=batch.step,
        agent_ids=batch.agent_ids[ids],
        observations=batch.observations[ids],
        action_mask=batch.action_mask[ids],
        positions=batch.positions[ids],
        loads=batch.loads[ids],
        queued=batch.queued[ids],
        world_shape=batch.world_shape,
    )
