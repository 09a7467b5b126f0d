"""C-SAF and C-SAF-11 (SPEC §7) on tiny hand-built worlds, with exact expectations.

The 16x16 layout (nest caches and their queues) is described in conftest.py. Moves: 0 north,
1 east, 2 south, 3 west, 4 JOIN.
"""

from __future__ import annotations

import numpy as np
from conftest import SE_QUEUE, agent, build_world, cells_of, resource

from formic_agent.policy import AgentBatch
from formic_baselines.csaf import CLIMB, LEAVE, NO_TRAIL, CSAF11Policy, CSAFPolicy
from formic_world import World, WorldConfig, generate_scenario
from formic_world.geometry import EAST, JOIN, SOUTH, WEST


def act(policy, world, result=None) -> np.ndarray:
    if result is None:
        return policy.act(AgentBatch.from_world(world))
    return policy.act(AgentBatch.from_world(world, observations=result.observations,
                                            action_mask=result.action_mask))


def drive(policy, world, steps: int, watch: int | None = None) -> list[int]:
    """Run ``steps`` steps; returns the actions chosen for agent ``watch``."""
    chosen = []
    for _ in range(steps):
        actions = act(policy, world)
        if watch is not None:
            chosen.append(int(actions[watch]))
        world.step(actions)
    return chosen


def nest_distance(row: int, col: int, size: int = 16) -> int:
    """Manhattan distance to the nearest nest cache."""
    h = size // 2
    return max(h - 1 - row, 0, row - h) + max(h - 1 - col, 0, col - h)


def episode(policy, size: int, n_agents: int, seed: int) -> float:
    world = World(generate_scenario(WorldConfig(height=size, width=size, n_agents=n_agents), seed=seed))
    policy.reset(n_agents, seed=seed)
    result = world.reset(world.scenario)
    while not world.done:
        result = world.step(act(policy, world, result))
    return world.score


def test_names_and_wipeout_flag():
    assert CSAFPolicy().name == "csaf" and CSAF11Policy().name == "csaf11"
    assert CSAFPolicy.uses_world_wipeouts and CSAF11Policy().view == 11


def test_searching_agent_next_to_a_resource_queue_steps_in_and_joins():
    # Resource (1,12), queue south from (2,12): the entry's neighbours (2,11) (2,13) (3,12).
    world = build_world([agent(1, 11)], resources=[resource(1, 12, SOUTH)])
    policy = CSAFPolicy()
    policy.reset(1, seed=0)
    assert drive(policy, world, 2, watch=0) == [SOUTH, JOIN]
    assert world.queue_of[0] == 4 and cells_of(world, 0) == (2, 12)


def test_loaded_agent_with_no_pheromone_around_heads_straight_for_the_nest():
    world = build_world([agent(1, 13, loaded=True)])
    policy = CSAFPolicy()
    policy.reset(1, seed=0)
    distances = [nest_distance(*cells_of(world, 0))]
    for _ in range(20):
        world.step(act(policy, world))
        if world.queued[0]:
            break
        distances.append(nest_distance(*cells_of(world, 0)))
    assert world.queue_of[0] in (0, 1, 2, 3)  # joined a cache queue
    assert distances == list(range(distances[0], distances[0] - len(distances), -1))
    assert (policy.ground.marked_at < 0).all() and not policy.ground.trails  # returning marks nothing


def test_loaded_agent_orbits_the_nest_along_a_cache_queue_to_its_entry():
    # NE queue holds 3 agents (entry (3,8)), SE holds 2 (entry (8,11)); drop-off is slow, so
    # the queues stand still. The agent at (6,9) sees no entry: it circles clockwise,
    # steps out around the SE queue and joins at its tail.
    queued = [agent(6, 8, True, 1), agent(5, 8, True, 1), agent(4, 8, True, 1),
              agent(*SE_QUEUE[0], True, 3), agent(*SE_QUEUE[1], True, 3)]
    world = build_world(queued + [agent(6, 9, loaded=True)], dropoff_rate=0.01)
    policy = CSAFPolicy()
    policy.reset(6, seed=0)
    assert drive(policy, world, 4, watch=5) == [SOUTH, EAST, EAST, JOIN]
    assert world.queue_of[5] == 3 and cells_of(world, 5) == SE_QUEUE[2]


def test_trail_is_laid_home_and_followed_uphill_by_an_agent_leaving_the_nest():
    # A joins the resource (2,13) at once, fills up, walks home colouring the trail. B sits
    # at the NE cache's spot 0 unloading for 25 steps, then looks for a trail and climbs it.
    size, key = 16, 3 * 16 + 13  # the trail is named by the queue's spot 0, (3,13)
    world = build_world([agent(3, 12), agent(6, 8, True, 1)], resources=[resource(2, 13, SOUTH)],
                        dropoff_rate=0.04)
    policy = CSAFPolicy()
    policy.reset(2, seed=0)
    path, states = [], []
    for _ in range(80):
        actions = act(policy, world)
        if world.carrying[0] and not world.queued[0]:
            path.append(cells_of(world, 0))  # where A stands when it acts (and colours)
        if not world.queued[1]:
            states.append(int(policy.state[1]))
        world.step(actions)
        if world.queue_of[1] == 4:
            break
    assert world.queue_of[1] == 4, "B never reached the resource queue"
    trail = policy.ground.trails[key]
    walked = list(dict.fromkeys(path))  # cells in the order A first stood on them
    laid = int(np.count_nonzero(trail != NO_TRAIL))
    assert walked[0] == (3, 13) and laid >= 3
    assert [int(trail[c]) for c in walked[:laid]] == list(range(laid))  # 0 at the resource
    assert nest_distance(*walked[laid - 1], size) <= 3  # the trail ends at the nest
    assert CLIMB in states and set(states) <= {LEAVE, CLIMB}  # B found the trail at the nest


def test_csaf11_heads_for_a_resource_entry_that_csaf_cannot_see():
    # Resource (12,14), queue west from (12,13): its nearest joinable cell (12,12) is 4 cells
    # east of the agent, outside C-SAF's 3x3 view.
    layout = dict(resources=[resource(12, 14, WEST)])
    blind = CSAFPolicy()
    blind.reset(1, seed=0)
    assert drive(blind, build_world([agent(12, 8)], **layout), 1, watch=0) == [SOUTH]  # outward
    world = build_world([agent(12, 8)], **layout)
    seeing = CSAF11Policy()
    seeing.reset(1, seed=0)
    assert drive(seeing, world, 5, watch=0) == [EAST, EAST, EAST, EAST, JOIN]
    assert world.queue_of[0] == 4 and cells_of(world, 0) == (12, 13)


def test_wipe_clears_every_mark_and_blocks_new_ones_for_the_window():
    world = World(generate_scenario(WorldConfig(height=32, width=32, n_agents=8), seed=1))
    policy = CSAFPolicy()
    policy.reset(8, seed=1)
    drive(policy, world, 200)
    ground = policy.ground
    assert (ground.marked_at >= 0).sum() > 50 and ground.trails
    policy.wipe(steps=10)
    assert (ground.marked_at < 0).all() and not ground.trails and not ground.trail_count.any()
    for _ in range(11):  # the window, and the step whose marks land at the next one
        world.step(act(policy, world))
        assert (ground.marked_at < 0).all() and not ground.trails
    for _ in range(40):  # then searching agents mark the ground again
        world.step(act(policy, world))
        if (ground.marked_at >= 0).any():
            break
    assert (ground.marked_at >= 0).any()


def test_split_batches_of_one_step_act_like_one_batch():
    world = World(generate_scenario(WorldConfig(height=32, width=32, n_agents=8), seed=2))
    whole, split = CSAFPolicy(), CSAFPolicy()
    whole.reset(8, seed=2)
    split.reset(8, seed=2)
    for _ in range(150):
        actions = act(whole, world)
        halves = [np.arange(0, 5), np.arange(5, 8)]
        parts = [split.act(AgentBatch.from_world(world, agent_ids=ids)) for ids in halves]
        assert np.array_equal(np.concatenate(parts), actions)
        world.step(actions)
    assert np.array_equal(whole.ground.marked_at, split.ground.marked_at)


def test_full_episodes_deposit_food():
    # Recorded when written (seed 0, 512 steps): 32x32 with 8 agents, C-SAF 103.0 and
    # C-SAF-11 98.0; 64x64 with 16 agents, C-SAF 123.0 and C-SAF-11 142.0. The floors leave
    # room for changes of the world's generator, not for a policy that stops foraging.
    assert episode(CSAFPolicy(), 32, 8, seed=0) >= 50
    assert episode(CSAF11Policy(), 32, 8, seed=0) >= 50
    assert episode(CSAFPolicy(), 64, 16, seed=0) >= 70
    assert episode(CSAF11Policy(), 64, 16, seed=0) >= 70


def test_same_seed_same_food():
    first = episode(CSAFPolicy(), 32, 8, seed=3)
    assert episode(CSAFPolicy(), 32, 8, seed=3) == first
    policy = CSAF11Policy()
    assert episode(policy, 32, 8, seed=3) == episode(policy, 32, 8, seed=3)  # reset forgets all
