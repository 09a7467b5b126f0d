"""Helpers for tiny hand-built worlds with exact, hand-checkable expectations.

The default world is 16x16: the nest caches are (7,7) NW, (7,8) NE, (8,7) SW, (8,8) SE and
their queues run (spot 0 first):
  queue 0, NW, west:  (7,6) (7,5) (7,4) (7,3) (7,2)
  queue 1, NE, north: (6,8) (5,8) (4,8) (3,8) (2,8)
  queue 2, SW, south: (9,7) (10,7) (11,7) (12,7) (13,7)
  queue 3, SE, east:  (8,9) (8,10) (8,11) (8,12) (8,13)
Resource i owns queue 4+i. An agent meant to stay put is given a move into a blocked cell or
a JOIN far from every queue: both leave it where it is while it still acts (pays the step,
deposits when carrying), unlike NO_ACTION.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping

import numpy as np

from formic_world import Scenario, World, WorldConfig
from formic_world.geometry import JOIN
from formic_world.scenario import AgentStart, ResourceSpec, validate_scenario

NW_QUEUE = [(7, 6), (7, 5), (7, 4), (7, 3), (7, 2)]
NE_QUEUE = [(6, 8), (5, 8), (4, 8), (3, 8), (2, 8)]
SW_QUEUE = [(9, 7), (10, 7), (11, 7), (12, 7), (13, 7)]
SE_QUEUE = [(8, 9), (8, 10), (8, 11), (8, 12), (8, 13)]


def resource(row: int, col: int, direction: int, capacity: int = 0) -> ResourceSpec:
    """A resource at (row, col) whose queue runs in ``direction``; capacity 0 = infinite."""
    return ResourceSpec(row, col, direction, capacity)


def agent(row: int, col: int, loaded: bool = False, cache_queue: int = -1) -> AgentStart:
    return AgentStart(row, col, loaded, cache_queue)


def build_scenario(
    agents: Iterable[AgentStart],
    resources: Iterable[ResourceSpec] = (),
    obstacles: Iterable[tuple[int, int]] = (),
    wipeout_starts: Iterable[int] = (),
    seed: int = 0,
    height: int = 16,
    width: int = 16,
    **config: object,
) -> Scenario:
    """A hand-made scenario, checked like a loaded file; ``config`` overrides WorldConfig fields."""
    agents, resources = tuple(agents), tuple(resources)
    if any(r.capacity > 0 for r in resources):
        config.setdefault("capacity", "finite")
    cfg = WorldConfig(height=height, width=width, n_agents=len(agents), **config)
    scenario = Scenario(
        config=cfg,
        seed=seed,
        obstacles=tuple(obstacles),
        resources=resources,
        agents=agents,
        wipeout_starts=tuple(wipeout_starts),
    )
    validate_scenario(scenario)
    return scenario


def build_world(agents: Iterable[AgentStart], **kwargs: object) -> World:
    return World(build_scenario(agents, **kwargs))


def step(world: World, actions: Mapping[int, int] | Iterable[int]):
    """Step with a full action list, or a {agent: action} dict (others JOIN: a no-op when
    they stand away from every queue entry)."""
    if isinstance(actions, Mapping):
        full = np.full(world.config.n_agents, JOIN, dtype=np.int64)
        for a, act in actions.items():
            full[a] = act
        actions = full
    return world.step(np.asarray(list(actions), dtype=np.int64))


def cells_of(world: World, agent_id: int) -> tuple[int, int]:
    return int(world.pos[agent_id, 0]), int(world.pos[agent_id, 1])

