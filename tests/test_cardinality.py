"""Cardinality-MR: role changes, hop-count relay, joining queues."""

from __future__ import annotations

import numpy as np

from formic_agent.policy import AgentBatch
from formic_baselines.cardinality import UNKNOWN, CardinalityPolicy
from formic_world import World, WorldConfig, generate_scenario
from formic_world.geometry import JOIN
from formic_world.scenario import AgentStart, ResourceSpec, Scenario

NORTH, EAST, WEST = 0, 1, 3
FAR_RESOURCE = ResourceSpec(16, 2, NORTH, 0)  # queue (15..11, 2) in a 20x20 world


def make_world(size, agents, resources=(FAR_RESOURCE,)) -> World:
    cfg = WorldConfig(height=size, width=size, n_agents=len(agents))
    starts = tuple(AgentStart(r, c, loaded, -1) for r, c, loaded in agents)
    return World(Scenario(cfg, 0, (), tuple(resources), starts, ()))


def step(world: World, policy: CardinalityPolicy) -> np.ndarray:
    actions = policy.act(AgentBatch.from_world(world))
    world.step(actions)
    return actions


def test_walker_with_no_beacon_in_view_becomes_a_beacon_and_stays_put():
    world = make_world(20, [(3, 3, False), (5, 15, False)])  # nest (rows/cols 9-10) out of view / in view
    policy = CardinalityPolicy()
    policy.reset(2, 0)
    step(world, policy)
    assert policy.is_beacon.tolist() == [True, True]
    assert world.pos.tolist() == [[3, 3], [5, 15]]  # beacons send a no-op
    assert policy.nest_hop[0] == UNKNOWN and policy.nest_hop[1] == 1  # the second sees a cache


def test_crowded_beacon_becomes_a_walker():
    agents = [(6, 6, False), (6, 7, False), (7, 6, False), (5, 5, False)]  # all within view of the nest
    for probability, walkers in ((1.0, 1), (0.0, 0)):
        world = make_world(20, agents)
        policy = CardinalityPolicy(conversion_probability=probability)
        policy.reset(4, 0)
        policy.is_beacon[:] = True
        policy.nest_hop[:] = 1
        step(world, policy)
        # Each sees three others; once one has left, the rest see only two and stay.
        assert np.count_nonzero(~policy.is_beacon) == walkers


def test_hop_counts_relay_along_a_line_of_beacons():
    # 48x48: nest at rows/cols 23-24. Beacons 4 apart eastwards; the first sees the caches, the
    # last sees a resource at (31, 45) whose queue runs west.
    line = [(26, 29, False), (26, 33, False), (26, 37, False), (26, 41, False)]
    world = make_world(48, line, resources=[ResourceSpec(31, 45, WEST, 0)])
    policy = CardinalityPolicy()
    policy.reset(4, 0)
    for _ in range(5):
        step(world, policy)
    assert policy.is_beacon.all()
    assert policy.nest_hop.tolist() == [1, 2, 3, 4]
    assert policy.resource_cells.tolist() == [[31, 45]]
    assert policy.res_hop[:, 0].tolist() == [4, 3, 2, 1]


def test_loaded_walker_next_to_a_cache_entry_joins():
    world = make_world(20, [(11, 11, True)])  # south of the SE cache queue's entry (10, 11)
    policy = CardinalityPolicy()
    policy.reset(1, 0)
    actions = step(world, policy)
    assert actions.tolist() == [JOIN]
    assert not policy.is_beacon[0]  # at a queue: it never stops there
    assert world.queued[0] and world.queue_of[0] == 3


def test_empty_walker_next_to_a_resource_entry_joins():
    world = make_world(20, [(15, 3, False)])  # east of the resource queue's entry (15, 2)
    policy = CardinalityPolicy()
    policy.reset(1, 0)
    actions = step(world, policy)
    assert actions.tolist() == [JOIN]
    assert world.queued[0] and world.queue_of[0] == 4
    assert policy.resource_cells.tolist() == [[16, 2]]  # learnt from the queue's markings


def _episode(seed: int, steps: int, **overrides) -> tuple[float, str, list]:
    world = World(generate_scenario(WorldConfig(height=32, width=32, n_agents=16, **overrides), seed=seed))
    policy = CardinalityPolicy()
    policy.reset(16, seed)
    result = world.reset(world.scenario)
    for _ in range(steps):
        batch = AgentBatch.from_world(world, observations=result.observations, action_mask=result.action_mask)
        result = world.step(policy.act(batch))
    return world.score, world.state_digest(), policy.is_beacon.tolist()


def test_full_episode_deposits_food():
    assert _episode(0, 512)[0] > 0
    assert _episode(1, 512, capacity="finite")[0] > 0


def test_same_seed_same_trajectory():
    assert _episode(2, 150) == _episode(2, 150)
