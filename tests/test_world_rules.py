"""Every rule of SPEC §1-4 on tiny hand-built worlds, with hand-checked exact expectations.

Layout of the default 16x16 world (nest caches, cache queues) is in conftest.py. Loads are
integer ticks with load_full = 10: gathering adds 1 tick a step, drop-off removes 5.
"""

from __future__ import annotations

import numpy as np
import pytest
from conftest import NW_QUEUE, agent, build_world, cells_of, resource, step
from scipy import ndimage

from formic_world import NO_ACTION, REWARD_PRESETS, RewardConfig, WorldConfig
from formic_world import world as world_module
from formic_world.geometry import (
    EAST,
    FREE,
    JOIN,
    NORTH,
    SOUTH,
    WEST,
    NEST_QUEUE_DIRECTIONS,
    RESOURCE,
    nest_cache_cells,
    queue_cells,
    strip_cells,
)
from formic_world.observation import (
    CH_BLOCKED,
    CH_CACHE_ENTRY,
    CH_CACHE_QUEUED,
    CH_CARRYING_AGENTS,
    CH_EMPTY_AGENTS,
    CH_PHEROMONE,
    CH_RESOURCE_ENTRY,
    CH_RESOURCE_QUEUED,
)
from formic_world.pheromones import curriculum_intensities

ALPHA, BETA = 0.97, 0.99
WAIT = MOVE = -0.05
# Resource at (1,10) whose queue runs south: (2,10) (3,10) (4,10) (5,10) (6,10); queue index 4.
R_SOUTH = resource(1, 10, SOUTH)
R_QUEUE = [(2, 10), (3, 10), (4, 10), (5, 10), (6, 10)]


def window(view: int, centre: tuple[int, int], cells) -> np.ndarray:
    """A (view, view) array with 1 at each world cell of ``cells`` inside the window."""
    out = np.zeros((view, view), dtype=np.float32)
    r = view // 2
    for row, col in cells:
        i, j = row - centre[0] + r, col - centre[1] + r
        if 0 <= i < view and 0 <= j < view:
            out[i, j] = 1.0
    return out


def reachable_from_nest(world) -> np.ndarray:
    labels, _ = ndimage.label(world.grid == FREE)
    return labels == labels[tuple(world.queue_cells[0, 0])]


# ---------------------------------------------------------------- joining


@pytest.mark.parametrize("start", [(2, 10), (2, 9), (2, 11), (3, 10)])
def test_empty_agent_joins_resource_queue_from_entry_or_neighbour(start):
    world = build_world([agent(*start)], resources=[R_SOUTH])
    assert [tuple(c) for c in world.queue_cells[4].tolist()] == R_QUEUE
    assert world.action_mask()[0, JOIN]
    result = step(world, [JOIN])
    assert cells_of(world, 0) == (2, 10)
    assert world.queue_of[0] == 4 and world.spot_of[0] == 0
    assert world.queue_members[4].tolist() == [0, -1, -1, -1, -1]
    assert result.rewards[0] == 0.0  # right join; no wait penalty on the joining step
    assert world.load[0] == 1  # served in the same step (phase 3 follows phase 2)


@pytest.mark.parametrize("start", [(7, 6), (6, 6), (8, 6), (7, 5)])
def test_carrying_agent_joins_cache_queue_from_entry_or_neighbour(start):
    world = build_world([agent(*start, loaded=True)])
    result = step(world, [JOIN])
    assert cells_of(world, 0) == (7, 6)
    assert world.queue_of[0] == 0 and world.spot_of[0] == 0
    assert result.rewards[0] == 0.0


def test_entry_is_first_spot_behind_last_queued_agent():
    # two loaded agents start in the NW queue: the entry is spot 2 (7,4)
    world = build_world(
        [agent(7, 6, True, 0), agent(7, 5, True, 0), agent(6, 4, True), agent(6, 6, True)]
    )
    assert world.entry_owner[7, 4] == 0
    assert (world.entry_owner == 0).sum() == 1
    mask = world.action_mask()
    assert mask[2, JOIN] and not mask[3, JOIN]  # (6,6) only touches spot 0, which is taken
    result = step(world, {2: JOIN, 3: JOIN})
    assert cells_of(world, 2) == (7, 4) and world.spot_of[2] == 2
    assert cells_of(world, 3) == (6, 6) and world.queue_of[3] == -1
    assert result.rewards[3] == RewardConfig().join_nothing


def test_nearest_queue_wins():
    # queue 4 entry (2,10), queue 5 entry (2,11); the agent stands on queue 5's entry
    world = build_world([agent(2, 11)], resources=[resource(1, 10, SOUTH), resource(1, 11, SOUTH)])
    step(world, [JOIN])
    assert world.queue_of[0] == 5 and cells_of(world, 0) == (2, 11)


@pytest.mark.parametrize("order, expected_cell", [((10, 12), (2, 10)), ((12, 10), (2, 12))])
def test_equal_distance_takes_lowest_queue_index(order, expected_cell):
    # entries (2,10) and (2,12) both touch (2,11); the resource listed first owns queue 4
    world = build_world([agent(2, 11)], resources=[resource(1, c, SOUTH) for c in order])
    step(world, [JOIN])
    assert world.queue_of[0] == 4 and cells_of(world, 0) == expected_cell


def test_wrong_type_join_costs_one_and_does_nothing():
    # empty agent next to the NW cache entry; loaded agent next to a resource entry
    world = build_world([agent(6, 6), agent(2, 11, loaded=True)], resources=[R_SOUTH])
    assert not world.action_mask()[:, JOIN].any()
    result = step(world, [JOIN, JOIN])
    assert result.rewards.tolist() == [-1.0, -1.0]
    assert cells_of(world, 0) == (6, 6) and cells_of(world, 1) == (2, 11)
    assert (world.queue_of == -1).all() and (world.queue_count == 0).all()


@pytest.mark.parametrize("loaded, queue, cell", [(False, 4, (5, 6)), (True, 0, (7, 6))])
def test_wrong_type_neighbour_does_not_block_right_join(loaded, queue, cell):
    # (6,6) touches the NW cache entry (7,6) and the entry (5,6) of a resource queue running west
    world = build_world([agent(6, 6, loaded=loaded)], resources=[resource(5, 7, WEST)])
    result = step(world, [JOIN])
    assert world.queue_of[0] == queue and cells_of(world, 0) == cell
    assert result.rewards[0] == 0.0


def test_full_queue_cannot_be_joined():
    queued = [agent(r, c, True, 0) for r, c in NW_QUEUE]
    world = build_world(queued + [agent(7, 1, loaded=True)])
    assert (world.entry_owner == 0).sum() == 0  # a full queue has no entry
    assert not world.action_mask()[5, JOIN]
    result = step(world, [JOIN] * 6)
    assert world.queue_of[5] == -1 and cells_of(world, 5) == (7, 1)
    assert result.rewards[5] == RewardConfig().join_nothing


def test_entry_occupied_by_another_agent_cannot_be_joined():
    # A (free, empty) stands on the entry (2,10); B touches it from (2,11)
    world = build_world([agent(2, 10), agent(2, 11)], resources=[R_SOUTH])
    mask = world.action_mask()
    assert mask[0, JOIN] and not mask[1, JOIN]  # A may join on its own cell
    result = step(world, [NORTH, JOIN])  # A bumps into the resource, B tries to join
    assert world.queue_of.tolist() == [-1, -1]
    assert cells_of(world, 1) == (2, 11)
    assert result.rewards[1] == RewardConfig().join_nothing
    step(world, [JOIN, EAST])  # A joins on its own cell; B walks away
    assert world.queue_of[0] == 4 and cells_of(world, 0) == (2, 10)


def test_finite_resource_with_no_unit_left_for_a_newcomer_is_not_joinable():
    # capacity 2: A and B take both units, C is refused. Obstacles at (3,12), (4,12) let B and C
    # stand still by bumping east.
    world = build_world(
        [agent(2, 10), agent(3, 11), agent(4, 11)],
        resources=[resource(1, 10, SOUTH, capacity=2)],
        obstacles=[(3, 12), (4, 12)],
        view_size=5,
    )
    step(world, [JOIN, EAST, EAST])
    assert world.resource_remaining[0] == 19
    obs = step(world, [JOIN, JOIN, EAST]).observations
    assert world.queue_members[4, :2].tolist() == [0, 1]
    assert world.resource_remaining[0] == 18  # 1.8 units for 2 queued agents: closed
    assert not world.action_mask()[2, JOIN]
    assert obs[2, CH_RESOURCE_ENTRY].sum() == 0  # the closed queue shows no entry
    result = step(world, [JOIN, JOIN, JOIN])
    assert world.queue_of[2] == -1 and cells_of(world, 2) == (4, 11)
    assert result.rewards[2] == RewardConfig().join_nothing


def test_finite_entry_shows_remaining_fraction():
    world = build_world(
        [agent(2, 10), agent(3, 11)],
        resources=[resource(1, 10, SOUTH, capacity=2)],
        obstacles=[(3, 12)],
        view_size=5,
    )
    obs = step(world, [JOIN, EAST]).observations
    # 19 of 20 ticks remain; B at (3,11) sees the entry (3,10) at window (2,1)
    expected = window(5, (3, 11), [(3, 10), (2, 10), (4, 10), (3, 9), (3, 11)])
    expected[2, 1] = np.float32(19 / 20)
    assert (obs[1, CH_RESOURCE_ENTRY] == expected).all()


# ------------------------------------------------------------------ queues


def test_queued_agent_actions_are_ignored():
    world = build_world([agent(2, 10)], resources=[R_SOUTH])
    step(world, [JOIN])
    for action in (NORTH, EAST, SOUTH, WEST, JOIN):
        assert not world.action_mask()[0].any()
        result = step(world, [action])
        assert cells_of(world, 0) == (2, 10) and world.queue_of[0] == 4
        assert result.rewards[0] == WAIT


def test_released_agent_blocks_queue_until_it_walks_away():
    world = build_world([agent(7, 6, True, 0), agent(7, 5, True, 0)], timing="nominal")
    result = step(world, [JOIN, JOIN])  # actions of queued agents are ignored
    assert world.load.tolist() == [5, 10] and result.rewards.tolist() == [WAIT, WAIT]
    assert result.food == 0.5 and world.score == 0.5

    result = step(world, [JOIN, JOIN])  # A empties: released, stays on spot 0
    assert world.load.tolist() == [0, 10] and world.score == 1.0
    assert result.rewards.tolist() == [WAIT + 10.0, WAIT]
    assert world.queue_of.tolist() == [-1, 0] and cells_of(world, 0) == (7, 6)
    assert world.queue_members[0].tolist() == [-1, 1, -1, -1, -1]
    assert world.entry_owner[7, 4] == 0  # entry: the spot behind B

    step(world, [EAST, JOIN])  # A bumps into the cache and stays: B cannot advance
    assert cells_of(world, 1) == (7, 5) and world.load[1] == 10

    result = step(world, [NORTH, JOIN])  # A walks away: B advances and (nominal) is served at once
    assert cells_of(world, 0) == (6, 6) and cells_of(world, 1) == (7, 6)
    assert world.spot_of[1] == 0 and world.load[1] == 5 and world.score == 1.5

    result = step(world, [JOIN, JOIN])
    assert world.load[1] == 0 and world.queue_of[1] == -1 and world.score == 2.0
    assert result.rewards[1] == WAIT + 10.0 and result.food == 0.5


def test_nominal_gathering_takes_exactly_ten_steps_and_pays_ten():
    world = build_world([agent(2, 10)], resources=[R_SOUTH], timing="nominal")
    result = step(world, [JOIN])
    assert world.load[0] == 1 and result.rewards[0] == 0.0
    for t in range(2, 10):
        result = step(world, [JOIN])
        assert world.load[0] == t and world.queued[0] and result.rewards[0] == WAIT
    result = step(world, [JOIN])  # the 10th step since joining
    assert world.load[0] == world.load_full == 10 and world.loads[0] == 1.0
    assert result.rewards[0] == WAIT + 10.0
    assert not world.queued[0] and world.carrying[0] and cells_of(world, 0) == (2, 10)
    assert world.intensity[0] == 1.0  # p <- 1 on leaving the resource full
    assert world.resource_remaining[0] == -1  # infinite


def test_nominal_resource_queue_advances_after_released_agent_leaves():
    world = build_world([agent(2, 10), agent(3, 11)], resources=[R_SOUTH], obstacles=[(3, 12)], timing="nominal")
    step(world, [JOIN, EAST])
    step(world, [JOIN, JOIN])  # B joins at spot 1
    assert world.queue_members[4, :2].tolist() == [0, 1]
    for _ in range(8):
        step(world, [JOIN, JOIN])
    assert world.load[0] == 10 and not world.queued[0] and world.load[1] == 0
    step(world, [EAST, JOIN])  # A leaves spot 0: B advances and gathers a first tick
    assert cells_of(world, 0) == (2, 11) and cells_of(world, 1) == (2, 10)
    assert world.spot_of[1] == 0 and world.load[1] == 1


def test_drop_off_takes_two_steps_and_scores_exactly_one():
    world = build_world([agent(6, 6, loaded=True)])
    result = step(world, [JOIN])
    assert cells_of(world, 0) == (7, 6) and world.load[0] == 5
    assert result.rewards[0] == 0.0 and result.food == 0.5 and world.score == 0.5
    result = step(world, [JOIN])
    assert world.load[0] == 0 and not world.queued[0] and not world.carrying[0]
    assert result.rewards[0] == WAIT + 10.0 and result.food == 0.5
    assert world.score == 1.0 and world.score_ticks == 10


# ----------------------------------------------- reference timing (SPEC §1)


def test_reference_gathering_takes_eleven_steps_and_pays_on_the_eleventh():
    world = build_world([agent(2, 10)], resources=[R_SOUTH])
    assert world.config.timing == "reference"
    result = step(world, [JOIN])  # joins straight onto an empty spot 0: served at once
    assert world.load[0] == 1 and world.queued[0] and result.rewards[0] == 0.0
    for t in range(2, 11):
        result = step(world, [JOIN])
        assert world.load[0] == t and world.queued[0] and result.rewards[0] == WAIT
    assert world.load[0] == 10 and world.queued[0]  # full after 10 steps, still docked
    result = step(world, [JOIN])  # the 11th step since joining
    assert not world.queued[0] and world.load[0] == 10 and result.rewards[0] == WAIT + 10.0
    assert world.intensity[0] == 1.0 and cells_of(world, 0) == (2, 10)


def test_reference_drop_off_takes_two_steps_from_a_direct_join():
    world = build_world([agent(6, 6, loaded=True)])
    result = step(world, [JOIN])  # onto the empty spot 0 of the NW cache queue: served this step
    assert cells_of(world, 0) == (7, 6) and world.load[0] == 5 and result.food == 0.5
    result = step(world, [JOIN])
    assert world.load[0] == 0 and not world.queued[0] and result.rewards[0] == WAIT + 10.0
    assert world.score == 1.0


def test_reference_queue_moving_up_serves_nobody_in_that_step():
    world = build_world([agent(7, 6, True, 0), agent(7, 5, True, 0)])
    step(world, [JOIN, JOIN])
    step(world, [JOIN, JOIN])  # A empties and is released on spot 0
    assert world.load.tolist() == [0, 10] and world.score == 1.0
    result = step(world, [NORTH, JOIN])  # A walks away: B moves up to spot 0 but is not served
    assert cells_of(world, 1) == (7, 6) and world.spot_of[1] == 0
    assert world.load[1] == 10 and result.food == 0.0 and world.score == 1.0
    assert result.rewards[1] == WAIT
    step(world, [EAST, JOIN])
    assert world.load[1] == 5 and world.score == 1.5
    result = step(world, [EAST, JOIN])
    assert world.load[1] == 0 and not world.queued[1] and result.rewards[1] == WAIT + 10.0


def test_reference_resource_queue_moves_up_then_gathers_eleven_steps():
    world = build_world([agent(2, 10), agent(3, 11)], resources=[R_SOUTH], obstacles=[(3, 12)])
    step(world, [JOIN, EAST])
    step(world, [JOIN, JOIN])  # B joins at spot 1
    for _ in range(9):
        step(world, [JOIN, JOIN])
    assert world.load[0] == 10 and not world.queued[0] and world.load[1] == 0  # 11 steps for A
    step(world, [EAST, JOIN])  # A leaves spot 0: B moves up, nothing gathered this step
    assert cells_of(world, 1) == (2, 10) and world.spot_of[1] == 0 and world.load[1] == 0
    for t in range(1, 11):
        step(world, [EAST, JOIN])
        assert world.load[1] == t and world.queued[1]
    step(world, [EAST, JOIN])
    assert not world.queued[1]


def cache_queue_scores(timing: str, steps: int) -> list[float]:
    """Score after each step at one cache whose queue starts full (five loaded agents); every
    released agent walks off north and keeps going, so the queue only waits for service."""
    world = build_world([agent(*cell, True, 0) for cell in NW_QUEUE], timing=timing)
    scores = []
    for _ in range(steps):
        step(world, {a: NORTH for a in range(5) if not world.queued[a]})
        scores.append(world.score)
    return scores


def test_nest_throughput_with_a_full_cache_queue_nominal_timing():
    # 2 service steps per agent; the next one moves up and is served as the last walks off:
    # one unit per 2 steps per cache (2 per step for the nest's 4 caches).
    assert cache_queue_scores("nominal", 10) == [0.5, 1, 1.5, 2, 2.5, 3, 3.5, 4, 4.5, 5]


def test_nest_throughput_with_a_full_cache_queue_reference_timing():
    # The move-up step serves nobody: one unit per 3 steps per cache (1.33 per step at the nest).
    assert cache_queue_scores("reference", 14) == [0.5, 1, 1, 1.5, 2, 2, 2.5, 3, 3, 3.5, 4, 4, 4.5, 5]


def test_timing_is_validated_and_defaults_to_reference():
    assert WorldConfig().timing == "reference"
    assert (WorldConfig().gather_steps, WorldConfig().dropoff_steps) == (11, 2)
    nominal = WorldConfig(timing="nominal")
    assert (nominal.gather_steps, nominal.dropoff_steps) == (10, 2)
    with pytest.raises(ValueError, match="timing must be one of"):
        WorldConfig(timing="referance")


# -------------------------------------------------------- finite resources


def assert_resource_layout_valid(world) -> None:
    """Resource cells, queues and strips are consistent, disjoint and reachable."""
    cfg = world.config
    assert (world.grid == RESOURCE).sum() == len(world.resource_pos)
    reserved = np.zeros(world.grid.shape, dtype=int)
    for cache, direction in zip(nest_cache_cells(cfg.height, cfg.width), NEST_QUEUE_DIRECTIONS):
        strip = strip_cells(cache, direction, cfg.queue_len)
        reserved[strip[:, 0], strip[:, 1]] += 1
    reach = reachable_from_nest(world)
    for i, (pos, d) in enumerate(zip(world.resource_pos, world.resource_dir)):
        assert world.grid[pos[0], pos[1]] == RESOURCE
        cells = queue_cells(tuple(pos), d, cfg.queue_len)
        assert (world.queue_cells[4 + i] == cells).all()
        assert (world.grid[cells[:, 0], cells[:, 1]] == FREE).all()
        assert reach[cells[:, 0], cells[:, 1]].all()
        strip = strip_cells(tuple(pos), d, cfg.queue_len)
        reserved[strip[:, 0], strip[:, 1]] += 1
    assert reserved.max() == 1
    for q in range(4):
        cells = world.queue_cells[q]
        assert reach[cells[:, 0], cells[:, 1]].all()


def test_depleted_resource_respawns_elsewhere():
    world = build_world([agent(2, 10)], resources=[resource(1, 10, SOUTH, capacity=1)], view_size=31)
    step(world, [JOIN])
    for _ in range(8):
        step(world, [JOIN])
    assert world.resource_remaining[0] == 1 and tuple(world.resource_pos[0]) == (1, 10)
    result = step(world, [JOIN])
    # the agent is full, free, on the old spot 0; a new resource exists elsewhere
    assert world.load[0] == 10 and not world.queued[0] and cells_of(world, 0) == (2, 10)
    assert result.rewards[0] == WAIT + 10.0
    new = tuple(int(v) for v in world.resource_pos[0])
    assert (world.grid == RESOURCE).sum() == 1 and world.grid[new] == RESOURCE
    if new != (1, 10):
        assert world.grid[1, 10] == FREE
    assert 40 <= world.resource_capacity[0] <= 80 and world.resource_capacity[0] % 10 == 0
    assert world.resource_remaining[0] == world.resource_capacity[0]
    strip = strip_cells(new, int(world.resource_dir[0]), 5)
    assert strip.min() >= 1 and strip.max() <= 14  # off the outer ring
    assert world.queue_count[4] == 0
    assert world.entry_owner[tuple(world.queue_cells[4, 0])] == 4
    assert_resource_layout_valid(world)
    # the view covers the whole world: blocked channel shows the new resource, not the old one
    blocked = result.observations[0, CH_BLOCKED, 13:29, 5:21]
    assert (blocked == (world.grid != FREE)).all()


def test_depletion_releases_queued_agents_where_they_stand():
    # The join rule never admits more agents than units, so the test lowers the remaining
    # stock by hand to force a depletion while B still waits.
    world = build_world(
        [agent(2, 10), agent(3, 11)], resources=[resource(1, 10, SOUTH, capacity=2)], obstacles=[(3, 12)]
    )
    step(world, [JOIN, EAST])
    step(world, [JOIN, JOIN])
    assert world.queue_members[4, :2].tolist() == [0, 1] and world.load[0] == 2
    world.resource_remaining[0] = 8  # exactly what A still needs
    for _ in range(7):
        step(world, [JOIN, JOIN])
    result = step(world, [JOIN, JOIN])
    assert world.load.tolist() == [10, 0]
    assert world.queue_of.tolist() == [-1, -1] and world.queue_count[4] == 0
    assert cells_of(world, 0) == (2, 10) and cells_of(world, 1) == (3, 10)
    assert result.rewards.tolist() == [WAIT + 10.0, WAIT]
    assert world.action_mask()[1, :4].any()  # B is a free agent again


def pocket_world():
    """24x24 world; a walled pocket (rows 0-5, cols 0-8) whose only door is (3,9) holds
    resource 1's queue (2,2)-(2,6). A resource on the door facing east would seal it."""
    wall = [(6, c) for c in range(10)] + [(r, 9) for r in range(6) if r != 3]
    return build_world(
        [agent(22, 22)],
        resources=[resource(20, 2, NORTH, capacity=4), resource(2, 1, EAST, capacity=4)],
        obstacles=wall,
        height=24,
        width=24,
    )


def test_respawn_never_seals_another_queue(monkeypatch):
    world = pocket_world()
    assert_resource_layout_valid(world)
    real = world_module.find_resource_strip
    draws = iter([(3, 9, EAST)])  # first offer the door, then draw normally

    def offer_door_first(rng, forbidden, queue_len):
        return next(draws, None) or real(rng, forbidden, queue_len)

    monkeypatch.setattr(world_module, "find_resource_strip", offer_door_first)
    world._respawn(4)  # drives the respawn rule directly (no policy needed)
    assert tuple(world.resource_pos[0]) != (3, 9)
    assert_resource_layout_valid(world)


def test_respawns_keep_every_queue_reachable():
    world = pocket_world()
    for _ in range(40):
        world._respawn(4)
        assert_resource_layout_valid(world)


# --------------------------------------------------------------- pheromones


def trail(n_steps: int, alpha: float = ALPHA, beta: float = BETA) -> list[float]:
    """P on the k-th cell of a straight walk after n steps, with the world's float operations:
    the k-th deposit is alpha^k (p decays by repeated products) and then decays n-1-k times."""
    values = []
    p = 1.0
    for k in range(n_steps):
        v = p
        for _ in range(n_steps - 1 - k):
            v *= beta
        values.append(v)
        p *= alpha
    return values


def test_loaded_agent_trail_is_alpha_k_beta_n_minus_1_minus_k():
    world = build_world([agent(12, 1, loaded=True)])
    for _ in range(4):
        result = step(world, [EAST])
    assert cells_of(world, 0) == (12, 5)
    expected = trail(4)
    assert world.pheromone[12, 1:5].tolist() == expected
    for k, v in enumerate(expected):
        assert v == pytest.approx(ALPHA**k * BETA ** (3 - k), rel=1e-14)
    assert world.pheromone.sum() == pytest.approx(sum(expected))  # nothing else
    # channel 7 reads P (float32); the agent sits at the centre (5,5) of its 11x11 window
    ch7 = result.observations[0, CH_PHEROMONE]
    assert ch7[5, 1:5].tolist() == np.float32(expected).tolist()
    assert ch7.sum() == pytest.approx(sum(expected), rel=1e-6)
    # walking back: the old, higher value on (12,4) dominates the new deposit alpha^5 (max)
    step(world, [WEST])  # deposits alpha^4 on (12,5)
    step(world, [WEST])  # deposits alpha^5 on (12,4), below alpha^3 * beta^2
    assert world.pheromone[12, 4] == expected[3] * BETA * BETA
    assert world.pheromone[12, 5] == ALPHA * ALPHA * ALPHA * ALPHA * BETA


@pytest.mark.parametrize("alpha, beta", [(ALPHA, BETA), (0.999, 0.9)])
def test_deposit_keeps_the_maximum(alpha, beta):
    # an agent standing still (JOIN far from queues) deposits alpha^j on the same cell each step
    world = build_world([agent(12, 1, loaded=True)], alpha=alpha, beta=beta)
    for _ in range(6):
        step(world, [JOIN])
    first, newest = beta**5, alpha**5  # the first deposit decayed, the latest fresh
    assert world.pheromone[12, 1] == pytest.approx(max(first, newest), rel=1e-14)
    assert world.intensity[0] == pytest.approx(alpha**6, rel=1e-14)


def test_fresh_deposit_reads_exactly_its_value_and_queued_agents_do_not_deposit():
    world = build_world([agent(6, 6, loaded=True)])
    result = step(world, [JOIN])  # deposits 1 on (6,6) before moving onto (7,6)
    assert world.pheromone[6, 6] == 1.0
    assert result.observations[0, CH_PHEROMONE, 4, 5] == 1.0
    step(world, [JOIN])
    assert world.pheromone[6, 6] == BETA and world.pheromone[7, 6] == 0.0


def test_flat_variant_has_no_gradient():
    world = build_world([agent(12, 1, loaded=True)], pheromone_variant="flat")
    for _ in range(5):
        step(world, [EAST])
    values = world.pheromone[12, 1:6]
    assert values == pytest.approx([BETA**4] * 5, rel=1e-13)  # alpha = beta: one level


def walk_row_zero(variant: str, seed: int = 0) -> np.ndarray:
    world = build_world([agent(0, 0, loaded=True)], pheromone_variant=variant, seed=seed)
    for _ in range(15):
        step(world, [EAST])
    return world.pheromone[0, :15].copy()


def test_noisy_variant_stays_within_its_bounds():
    n = 15
    values = walk_row_zero("noisy")
    standard = np.array(trail(n))
    decay = BETA ** (n - 1 - np.arange(n))
    ratio = values / standard
    assert (ratio >= 0.8 - 1e-12).all() and (ratio <= 1.2 + 1e-12).all()
    assert (values <= decay + 1e-12).all()  # each deposit clipped to 1
    assert np.ptp(ratio) > 0.05  # noise is really there
    assert not np.array_equal(values, walk_row_zero("noisy", seed=1))


def test_random_variant_deposits_uniform_in_02_1():
    n = 15
    values = walk_row_zero("random")
    deposited = values / BETA ** (n - 1 - np.arange(n))
    assert (deposited >= 0.2 - 1e-12).all() and (deposited <= 1.0 + 1e-12).all()
    assert np.ptp(deposited) > 0.1
    assert not np.array_equal(values, walk_row_zero("random", seed=1))


def test_wipeout_zeroes_and_silences_pheromone_for_its_steps():
    # wipeout starting at t=3 (the 4th step) lasting 100 steps
    world = build_world([agent(12, 1, loaded=True)], wipeout_starts=[3], episode_steps=200)
    moves = [EAST, WEST] * 60
    for t in range(3):
        step(world, [moves[t]])
    assert world.pheromone.max() > 0.9
    for t in range(3, 103):
        result = step(world, [moves[t]])
        assert world.pheromone.max() == 0.0, t
        assert result.observations[0, CH_PHEROMONE].max() == 0.0, t
    result = step(world, [moves[103]])  # t = 103: deposits resume
    p = 1.0
    for _ in range(103):
        p *= ALPHA  # p kept decaying during the wipeout (one factor per action)
    cell = (12, 1) if moves[103] == EAST else (12, 2)
    assert world.pheromone[cell] == p and world.pheromone.sum() == p
    assert result.observations[0, CH_PHEROMONE].max() == np.float32(p)


def test_wipeout_hides_highways_too():
    world = build_world(
        [agent(12, 12)], resources=[resource(1, 6, SOUTH)], highway_intensity=1.0,
        wipeout_starts=[2], episode_steps=120,
    )
    highway_peak = world.highways.max()  # beta^5 at the resource end of the 6-cell path
    assert world.visible_pheromone().max() == highway_peak == pytest.approx(BETA**5, rel=1e-14)
    seen = []
    for _ in range(103):
        step(world, [JOIN])
        seen.append(world.visible_pheromone().max())
    assert seen[0] > 0 and seen[1] > 0  # steps 0 and 1
    assert seen[2:102] == [0.0] * 100  # after steps 2..101: the wipeout
    assert seen[102] == highway_peak  # after step 102: back


def test_highways_follow_greedy_path_with_trail_values_and_are_observed_by_max():
    # resource 0 at (1,6), queue running south, spot 0 at (2,6): straight path to the NW cache
    # spot 0 (7,6), n = 6. Resource 1 at (1,5), spot 0 (2,5): greedy path to (7,6) goes south
    # to (6,5), then east on the tie (N, E, S, W order) to (6,6), then south, n = 7.
    world = build_world(
        [agent(5, 6, loaded=True)],
        resources=[resource(1, 6, SOUTH), resource(1, 5, SOUTH)],
        highway_intensity=0.5,
    )
    path0 = [(2, 6), (3, 6), (4, 6), (5, 6), (6, 6), (7, 6)]
    path1 = [(2, 5), (3, 5), (4, 5), (5, 5), (6, 5), (6, 6), (7, 6)]
    expected = np.zeros((16, 16))
    for path in (path0, path1):
        n = len(path)
        for k, cell in enumerate(path):
            expected[cell] = max(expected[cell], ALPHA**k * BETA ** (n - 1 - k))
    assert world.highways == pytest.approx(expected, rel=1e-14, abs=0)
    assert world.highways[6, 6] == pytest.approx(ALPHA**4 * BETA, rel=1e-14)  # path 0 wins
    result = step(world, [WEST])  # deposits 1 on (5,6)
    visible = world.visible_pheromone()
    assert visible[5, 6] == 1.0
    assert visible[3, 6] == pytest.approx(0.5 * ALPHA * BETA**4, rel=1e-14)
    assert world.highways == pytest.approx(expected, rel=1e-14, abs=0)  # static
    ch7 = result.observations[0, CH_PHEROMONE]  # agent now at (5,5): window centre
    assert ch7[5, 6] == 1.0 and ch7[3, 6] == np.float32(visible[3, 6])


def test_curriculum_schedule():
    assert curriculum_intensities(0) == (1.0, 0.0)
    assert curriculum_intensities(4999) == (1.0, 0.0)
    assert curriculum_intensities(7500) == (0.5, 0.5)
    assert curriculum_intensities(10000) == (0.0, 1.0)
    assert curriculum_intensities(50, start=10, end=90) == (0.5, 0.5)


# -------------------------------------------------------------- observation


def hand_built_observation_world(view_size: int = 11):
    """Agent 0 (empty) at (4,4) under an obstacle at (3,4); resource at (1,2) with a queue
    running east whose spot 0 (1,3) agent 1 joins; agent 2 loaded in the NW cache queue;
    agent 3 loaded at (5,5) deposits 1 there."""
    world = build_world(
        [agent(4, 4), agent(2, 3), agent(7, 6, True, 0), agent(5, 5, loaded=True)],
        resources=[resource(1, 2, EAST)],
        obstacles=[(3, 4)],
        view_size=view_size,
    )
    result = step(world, [NORTH, JOIN, JOIN, JOIN])
    assert cells_of(world, 0) == (4, 4) and world.queue_of.tolist() == [-1, 4, 0, -1]
    assert world.load.tolist() == [0, 1, 5, 10]
    return world, result


def test_every_observation_channel_in_a_hand_built_state():
    world, result = hand_built_observation_world()
    obs = result.observations
    assert obs.shape == (4, 8, 11, 11) and obs.dtype == np.float32
    me = obs[0]
    c = (4, 4)
    assert (me[CH_EMPTY_AGENTS] == window(11, c, [(4, 4)])).all()
    assert (me[CH_CARRYING_AGENTS] == window(11, c, [(1, 3), (7, 6), (5, 5)])).all()
    outside = [(-1, j) for j in range(-1, 10)] + [(i, -1) for i in range(-1, 10)]
    blocked = outside + [(3, 4), (1, 2), (7, 7), (7, 8), (8, 7), (8, 8)]
    assert (me[CH_BLOCKED] == window(11, c, blocked)).all()
    # resource entry is spot 1 (1,4): value 1 (infinite); its free neighbours hold 1
    assert (me[CH_RESOURCE_ENTRY] == window(11, c, [(1, 4), (0, 4), (2, 4), (1, 3), (1, 5)])).all()
    cache_entries = [
        (7, 5), (6, 5), (8, 5), (7, 4), (7, 6),  # NW: spot 1 and its free neighbours
        (6, 8), (5, 8), (6, 7), (6, 9),  # NE: spot 0, (7,8) is a cache
        (9, 7), (9, 6), (9, 8),  # SW: spot 0 (row 10 is outside the window)
        (8, 9), (7, 9), (9, 9),  # SE: spot 0 ((8,10) is outside the window)
    ]
    assert (me[CH_CACHE_ENTRY] == window(11, c, cache_entries)).all()
    assert (me[CH_RESOURCE_QUEUED] == window(11, c, [(1, 3)])).all()
    assert (me[CH_CACHE_QUEUED] == window(11, c, [(7, 6)])).all()
    assert (me[CH_PHEROMONE] == window(11, c, [(5, 5)])).all()  # a fresh deposit reads 1


def test_observation_at_the_far_corner_reads_outside_as_blocked():
    world = build_world([agent(15, 15)], view_size=5)
    obs = step(world, [SOUTH]).observations[0]  # bumps into the border
    expected = np.zeros((5, 5), dtype=np.float32)
    expected[3:, :] = 1
    expected[:, 3:] = 1
    assert (obs[CH_BLOCKED] == expected).all()
    assert obs[CH_EMPTY_AGENTS, 2, 2] == 1 and obs[CH_EMPTY_AGENTS].sum() == 1
    assert obs[[CH_RESOURCE_ENTRY, CH_CACHE_ENTRY, CH_PHEROMONE]].sum() == 0


@pytest.mark.parametrize("view", [5, 21])
def test_view_sizes_cut_the_same_maps(view):
    _, reference = hand_built_observation_world(11)
    _, result = hand_built_observation_world(view)
    obs = result.observations
    assert obs.shape == (4, 8, view, view)
    r = view // 2
    big, small = (obs, reference.observations) if view > 11 else (reference.observations, obs)
    rb, rs = big.shape[-1] // 2, small.shape[-1] // 2
    assert (big[..., rb - rs : rb + rs + 1, rb - rs : rb + rs + 1] == small).all()
    # agent 0 at (4,4): rows/cols below 0 are outside the world
    outside = np.zeros((view, view), dtype=bool)
    outside[: max(0, r - 4), :] = True
    outside[:, : max(0, r - 4)] = True
    assert (obs[0, CH_BLOCKED][outside] == 1).all()
    assert (obs[0, [0, 1, 3, 4, 5, 6, 7]][:, outside] == 0).all()


def test_hidden_pheromones_read_zero():
    world = build_world([agent(5, 5, loaded=True)], pheromones_visible=False)
    obs = step(world, [JOIN]).observations
    assert world.pheromone[5, 5] == 1.0 and obs[0, CH_PHEROMONE].sum() == 0


# ------------------------------------------------------ validity and filter


def test_validity_mask():
    world = build_world(
        [agent(0, 0), agent(12, 1), agent(12, 2), agent(2, 10), agent(6, 6, loaded=True)],
        resources=[R_SOUTH],
        obstacles=[(11, 1)],
    )
    mask = world.action_mask()
    assert mask[0].tolist() == [False, True, True, False, False]  # corner
    assert mask[1].tolist() == [False, False, True, True, False]  # obstacle N, agent E
    assert mask[2].tolist() == [True, True, True, False, False]
    assert mask[3].tolist() == [False, True, True, True, True]  # resource N; on the entry
    assert mask[4].tolist() == [True, True, True, True, True]


def test_no_valid_action_gives_all_false():
    world = build_world([agent(0, 0)], obstacles=[(0, 1), (1, 0)])
    assert not world.action_mask().any()
    assert not world.training_action_mask().any()
    result = step(world, [SOUTH])
    assert cells_of(world, 0) == (0, 0) and result.rewards[0] == MOVE


def test_training_filter_carrying_agents_head_for_the_nest():
    world = build_world(
        [agent(2, 2, loaded=True), agent(12, 12, loaded=True), agent(2, 13, loaded=True)],
    )
    filtered = world.training_action_mask()
    # nest centre (7.5, 7.5): from (2,2) north and west point away
    assert filtered[0].tolist() == [False, True, True, False, False]
    assert filtered[1].tolist() == [True, False, False, True, False]
    assert filtered[2].tolist() == [False, False, True, True, False]


def test_training_filter_allows_away_moves_when_nothing_else_is_possible():
    world = build_world([agent(2, 2, loaded=True)], obstacles=[(2, 3), (3, 2)])
    assert world.training_action_mask()[0].tolist() == [True, False, False, True, False]


def test_training_filter_fallback_counts_moves_only():
    # Interpretation: JOIN does not count as "another move". On the NW entry (7,6) with south
    # blocked, both remaining moves point away from the nest, so both come back.
    world = build_world([agent(7, 6, loaded=True)], obstacles=[(8, 6)])
    assert world.action_mask()[0].tolist() == [True, False, False, True, True]
    assert world.training_action_mask()[0].tolist() == [True, False, False, True, True]


def test_training_filter_empty_agents_do_not_reverse():
    world = build_world([agent(12, 1), agent(14, 2)], obstacles=[(13, 4), (15, 4), (14, 5)])
    assert world.training_action_mask()[0, :4].all()  # no previous move yet
    step(world, [EAST, EAST])
    step(world, [EAST, EAST])  # agent 1 ends at (14,4), a dead end
    filtered = world.training_action_mask()
    assert filtered[0].tolist() == [True, True, True, False, False]
    assert world.action_mask()[1].tolist() == [False, False, False, True, False]
    assert filtered[1].tolist() == [False, False, False, True, False]  # the only move


def test_training_filter_reverse_uses_last_successful_move():
    # Interpretation: a failed move leaves "the previous move" unchanged
    world = build_world([agent(12, 1)], obstacles=[(11, 2)])
    step(world, [EAST])  # (12,1) -> (12,2)
    step(world, [NORTH])  # blocked by (11,2)
    assert cells_of(world, 0) == (12, 2)
    assert world.training_action_mask()[0].tolist() == [False, True, True, False, False]


def test_queued_agents_have_no_valid_action():
    world = build_world([agent(7, 6, True, 0)])
    assert not world.action_mask().any() and not world.training_action_mask().any()


# ------------------------------------------------------------------ rewards


def test_every_reward():
    world = build_world(
        [agent(12, 1), agent(0, 0), agent(6, 6), agent(2, 11), agent(6, 9, loaded=True), agent(14, 14)],
        resources=[R_SOUTH],
    )
    result = step(world, [EAST, NORTH, JOIN, JOIN, JOIN, JOIN])
    # move, failed move, wrong join, right join (resource), right join (cache), join nothing
    assert result.rewards.tolist() == [MOVE, MOVE, -1.0, 0.0, 0.0, RewardConfig().join_nothing]


def test_rewards_come_from_configuration():
    rewards = RewardConfig(move=-0.5, queue_wait=-0.25, collect=3.0, deposit=7.0, join_right=0.5, join_wrong=-2.0)
    world = build_world([agent(6, 6, loaded=True), agent(12, 1), agent(2, 2)], rewards=rewards)
    result = step(world, [JOIN, EAST, JOIN])
    assert result.rewards.tolist() == [0.5, -0.5, -0.05]
    result = step(world, [JOIN, EAST, JOIN])
    assert result.rewards[0] == -0.25 + 7.0
    world = build_world([agent(2, 10), agent(6, 6)], resources=[R_SOUTH], rewards=rewards)
    assert step(world, [JOIN, JOIN]).rewards.tolist() == [0.5, -2.0]
    for _ in range(10):  # reference timing: the 11th service step releases the full agent
        result = step(world, [JOIN, NORTH])
    assert result.rewards[0] == -0.25 + 3.0


# ----------------------------------------------------------- step ordering


def predicted_orders(seed: int, n: int, steps: int) -> list[np.ndarray]:
    """The permutations the world draws, one per step (standard variant: nothing else)."""
    rng = np.random.default_rng([seed, 1])
    return [rng.permutation(n) for _ in range(steps)]


def test_two_agents_wanting_one_cell_first_in_order_wins():
    outcomes = set()
    for seed in range(8):
        world = build_world([agent(12, 1), agent(12, 3)], seed=seed)
        step(world, [EAST, WEST])
        order = predicted_orders(seed, 2, 1)[0]
        winner = int(order[0])
        assert cells_of(world, winner) == (12, 2)
        assert cells_of(world, 1 - winner) == [(12, 1), (12, 3)][1 - winner]
        outcomes.add(winner)
    assert outcomes == {0, 1}


def test_later_agents_see_earlier_moves():
    # a follows b east: a succeeds only if b moved first
    outcomes = set()
    for seed in range(8):
        world = build_world([agent(12, 1), agent(12, 2)], seed=seed)
        step(world, [EAST, EAST])
        order = predicted_orders(seed, 2, 1)[0].tolist()
        b_first = order == [1, 0]
        assert cells_of(world, 1) == (12, 3)
        assert cells_of(world, 0) == ((12, 2) if b_first else (12, 1))
        outcomes.add(b_first)
    assert outcomes == {True, False}


def test_agents_never_swap():
    for seed in range(6):
        world = build_world([agent(12, 1), agent(12, 2), agent(13, 1), agent(14, 1)], seed=seed)
        result = step(world, [EAST, WEST, SOUTH, NORTH])
        assert [cells_of(world, a) for a in range(4)] == [(12, 1), (12, 2), (13, 1), (14, 1)]
        assert (result.rewards == MOVE).all()
        assert (world.agent_at >= 0).sum() == 4


# ------------------------------------------------------------ episode end


def test_episode_ends_after_its_length_and_rejects_bad_actions():
    world = build_world([agent(12, 1)], episode_steps=3)
    with pytest.raises(ValueError):
        world.step(np.array([5]))
    with pytest.raises(ValueError):
        world.step(np.array([0, 0]))
    results = [step(world, [EAST]) for _ in range(3)]
    assert [r.done for r in results] == [False, False, True] and world.done and world.t == 3
    with pytest.raises(RuntimeError):
        step(world, [EAST])
    assert WorldConfig(episode_steps=1024).episode_steps == 1024  # both lengths available


def test_missing_action_does_nothing():
    world = build_world([agent(12, 1, loaded=True), agent(7, 6, True, 0)])
    result = step(world, [NO_ACTION, NO_ACTION])
    assert cells_of(world, 0) == (12, 1) and world.pheromone.max() == 0.0
    assert world.intensity[0] == 1.0 and result.rewards.tolist() == [0.0, WAIT]  # queued: waits
    assert world.load[1] == 5  # service goes on


def test_id_agent_order_lets_the_lowest_id_move_first():
    for seed in range(4):
        world = build_world([agent(12, 3), agent(12, 1)], seed=seed, agent_order="id")
        step(world, [WEST, EAST])
        assert cells_of(world, 0) == (12, 2) and cells_of(world, 1) == (12, 1)
    with pytest.raises(ValueError, match="agent_order must be one of"):
        WorldConfig(agent_order="sorted")


def test_reference_training_filter_keeps_the_two_best_aligned_possible_moves():
    # Nest centre (7.5, 7.5). From (2,2) south and east point home; with east blocked by an
    # agent the reference keeps south and the better of the two away moves (north before
    # west on a tie), where the paper's filter keeps south alone.
    starts = [agent(2, 2, loaded=True), agent(2, 3)]
    paper = build_world(starts).training_action_mask()
    reference = build_world(starts, training_filter="reference").training_action_mask()
    assert paper[0].tolist() == [False, False, True, False, False]
    assert reference[0].tolist() == [True, False, True, False, False]
    free = build_world([agent(2, 2, loaded=True)], training_filter="reference")
    assert free.training_action_mask()[0].tolist() == [False, True, True, False, False]
    with pytest.raises(ValueError, match="training_filter must be one of"):
        WorldConfig(training_filter="strict")


def test_reference_rewards_pay_near_resources_more_and_charge_blocked_steps():
    rewards = REWARD_PRESETS["reference"]
    assert (rewards.deposit, rewards.blocked, rewards.join_nothing) == (5.0, -0.5, -0.5)
    world = build_world([agent(2, 10), agent(12, 0), agent(14, 14)], resources=[R_SOUTH], rewards=rewards)
    result = step(world, [JOIN, WEST, EAST])  # agent 1 walks into the west wall; agent 2 moves
    assert result.rewards.tolist() == [0.0, -0.5, MOVE]
    for _ in range(10):
        result = step(world, [JOIN, JOIN, WEST])
    distance = np.hypot(1 - 7.5, 10 - 7.5)  # resource (1,10) to the nest centre
    assert result.rewards[0] == pytest.approx(WAIT + 10.0 * np.exp(-0.0115 * distance), abs=1e-12)
    assert result.rewards[1] == -0.5  # a JOIN that reaches no queue
    loaded = build_world([agent(6, 6, loaded=True)], rewards=rewards)
    step(loaded, [JOIN])
    assert step(loaded, [JOIN]).rewards[0] == WAIT + 5.0
