"""C-SAF and C-SAF-11 (SPEC §7) on tiny hand-built worlds, with exact expectations.

The 16x16 layout (nest caches and their queues) is described in conftest.py. Moves: 0 north,
1 east, 2 south, 3 west, 4 JOIN.
"""

from __future__ import annotations

import json

import numpy as np
import pytest
from conftest import SE_QUEUE, agent, build_world, cells_of, resource, step

from formic_runtime.episode import run_episode
from formic_agent.policy import AgentBatch, Policy
from formic_runtime.registry import (
    POLICY_NAMES,
    POLICY_WORLD_OVERRIDES,
    apply_world_overrides,
    make_policy,
    world_overrides,
)
from formic_runtime.team import Team
from formic_baselines.csaf import CLIMB, LEAVE, NO_TRAIL, CSAF11Policy, CSAFPolicy, PheromoneGround
from formic_world import Scenario, World, WorldConfig, generate_scenario
from formic_world.geometry import EAST, JOIN, NORTH, SOUTH, WEST


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
    assert CSAFPolicy.wipe is not Policy.wipe and CSAFPolicy.shares_team_memory and CSAF11Policy().view == 11


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


# ------------------------------------------------------------ the reference variant (csaf-ref)
def act_for(policy, world, ids=(0,)) -> list[int]:
    """The policy drives only ``ids``; the other agents stand still (a JOIN away from queues)."""
    return policy.act(AgentBatch.from_world(world, agent_ids=np.array(ids))).tolist()


def drive_one(policy, world, steps: int) -> list[int]:
    """Agent 0 driven by ``policy`` for ``steps`` steps; returns its actions."""
    chosen = []
    for _ in range(steps):
        (action,) = act_for(policy, world)
        chosen.append(action)
        step(world, {0: action})
    return chosen


def test_reference_variant_names_and_registry():
    assert CSAFPolicy(reference=True).name == "csaf-ref"
    assert CSAF11Policy(reference=True).name == "csaf11-ref" and CSAF11Policy(reference=True).view == 11
    for name in ("csaf-ref", "csaf11-ref"):
        policy = make_policy(name)
        assert policy.name == name and policy.reference and ":" not in name and name in POLICY_NAMES
    assert not make_policy("csaf").reference and not make_policy("csaf11").reference


def test_blocked_reference_agent_retries_its_move_while_the_default_steps_aside():
    # A loaded agent at (2,7) with no pheromone around heads straight south for the nest;
    # an agent that never moves stands at (3,7).
    def world():
        return build_world([agent(2, 7, loaded=True), agent(3, 7)])

    ref, default = CSAFPolicy(reference=True), CSAFPolicy()
    ref.reset(2, seed=0)
    default.reset(2, seed=0)
    w = world()
    assert drive_one(ref, w, 6) == [SOUTH] * 6  # tries the taken cell again and again
    assert cells_of(w, 0) == (2, 7)
    step(w, {1: EAST})  # the way clears: it goes on at once
    assert drive_one(ref, w, 1) == [SOUTH] and cells_of(w, 0) == (3, 7)
    w = world()
    assert drive_one(default, w, 1) != [SOUTH] and cells_of(w, 0) != (2, 7)  # stepped aside


def test_reference_ties_go_north_east_south_west():
    # A loaded agent at (3,3) descends the search gradient: neighbours marked at the same
    # step are equally good ways home.
    def first_move(policy, marked, seed=0):
        policy.reset(1, seed=seed)
        policy.ground = PheromoneGround((16, 16), policy.search_decay)
        for cell in marked:
            policy.ground.marked_at[cell] = 5
        return act_for(policy, build_world([agent(3, 3, loaded=True)]))[0]

    n, e, s, w = (2, 3), (3, 4), (4, 3), (3, 2)
    ref = CSAFPolicy(reference=True)
    # The reference breaks a tie of the two weakest free marks by the move best aligned with
    # the way to the world's centre (7.5, 7.5): south and east are equally good, east first.
    assert first_move(ref, [n, e, s, w]) == EAST
    assert first_move(ref, [w, s]) == EAST  # even where that cell is not marked
    assert first_move(ref, [n, w]) == EAST
    assert first_move(ref, [w, s, e]) == EAST
    assert {first_move(ref, [n, e, s, w], seed) for seed in range(8)} == {EAST}
    assert len({first_move(CSAFPolicy(), [n, e, s, w], seed) for seed in range(8)}) > 1
    # Diagonal offsets: the two moves towards the nest in N, E, S, W order.
    for cell, move in (((2, 2), EAST), ((13, 13), NORTH), ((2, 13), SOUTH), ((13, 2), NORTH)):
        ref.reset(1, seed=0)
        assert act_for(ref, build_world([agent(*cell, loaded=True)]))[0] == move


def test_reference_descent_goes_round_an_agent_on_the_oldest_mark():
    # Issue 25: the port's reference variant waited behind an agent standing on the oldest
    # marked neighbour (a climber coming up the trail the other way, which waits too: the
    # team's gridlock at the nest). The authors' code takes the oldest marked neighbour no
    # agent stands on, never straight back. Loaded agent 0 at (3,3) (marked at step 2):
    # south (4,3) marked at step 1 holds agent 1, east (3,4) at step 4, west (3,2) at step 6;
    # then from (3,4), south (4,4) at step 3 and west (3,3), the way back, is the oldest.
    def run(policy, steps):
        policy.reset(2, seed=0)
        policy.ground = PheromoneGround((16, 16), policy.search_decay)
        for cell, at in (((3, 3), 2), ((4, 3), 1), ((3, 4), 4), ((3, 2), 6), ((4, 4), 3)):
            policy.ground.marked_at[cell] = at
        world = build_world([agent(3, 3, loaded=True), agent(4, 3)])
        return drive_one(policy, world, steps), cells_of(world, 0)

    assert run(CSAFPolicy(reference=True), 2) == ([EAST, SOUTH], (4, 4))
    assert run(CSAF11Policy(reference=True), 2) == ([EAST, SOUTH], (4, 4))
    # The earlier port descended only to marks older than any reached on this trip: it
    # retried the taken cell for as long as agent 1 stood there.
    policy = CSAFPolicy(reference=True)
    policy._descend_reference = policy._descend
    assert run(policy, 4) == ([SOUTH] * 4, (3, 3))


def test_reference_loaded_agent_scans_for_no_cache_entry():
    # Four agents fill the NE cache queue up to (3,8): its entry is (2,8). A loaded agent at
    # (2,12), nothing marked: C-SAF-11 heads west for the entry's neighbour (2,9) in its view;
    # the reference, as the authors' C-SAF-11 (whose only scan is for resources), goes home
    # (south, the larger offset) and joins only where JOIN is valid.
    def first_move(policy):
        queued = [agent(r, 8, True, 1) for r in (6, 5, 4, 3)]
        policy.reset(5, seed=0)
        return act_for(policy, build_world(queued + [agent(2, 12, loaded=True)]), ids=(4,))[0]

    assert first_move(CSAF11Policy()) == WEST
    assert first_move(CSAF11Policy(reference=True)) == SOUTH


def test_reference_search_fallback_ignores_agents():
    # Searching north at (3,3); itself, north, east and south marked; west unmarked but
    # taken by an agent. The default climbs to a newer mark (north or east); the reference
    # takes the unmarked cell anyway and waits for it.
    def first_moves(policy, steps=3):
        policy.reset(2, seed=0)
        policy.ground = PheromoneGround((16, 16), policy.search_decay)
        for cell, at in (((3, 3), 1), ((2, 3), 2), ((3, 4), 2), ((4, 3), 2)):
            policy.ground.marked_at[cell] = at
        return drive_one(policy, build_world([agent(3, 3), agent(3, 2)]), steps)

    assert first_moves(CSAFPolicy(reference=True)) == [WEST] * 3
    assert first_moves(CSAFPolicy(), 1)[0] in (NORTH, EAST)


def test_reference_agent_that_just_unloaded_waits_while_its_view_corner_is_taken():
    # A unloads at the NE cache's spot 0 (6,8); B stands 5 south and 5 east of it, at (11,13).
    def unload(policy):
        world = build_world([agent(6, 8, True, 1), agent(11, 13)])
        policy.reset(2, seed=0)
        for _ in range(10):
            step(world, {0: act_for(policy, world)[0]})
            if not world.queued[0]:
                return world
        raise AssertionError("never unloaded")

    ref = CSAFPolicy(reference=True)
    world = unload(ref)
    assert drive_one(ref, world, 3) == [SOUTH] * 3 and cells_of(world, 0) == (6, 8)  # into the cache
    step(world, {1: EAST})
    assert drive_one(ref, world, 1) != [SOUTH] and cells_of(world, 0) != (6, 8)
    default = CSAFPolicy()
    world = unload(default)
    drive_one(default, world, 1)
    assert cells_of(world, 0) != (6, 8)


def test_reference_variant_draws_no_random_numbers():
    scenario = apply_world_overrides(
        generate_scenario(WorldConfig(height=32, width=32, n_agents=8), seed=4), ["csaf-ref"])
    runs = []
    for seed in (0, 1):  # the policy's seed changes nothing
        world, policy = World(scenario), CSAF11Policy(reference=True)
        policy.reset(8, seed=seed)
        runs.append(drive(policy, world, 120, watch=3))
        assert policy.rng.bit_generator.state == np.random.default_rng([seed, 13]).bit_generator.state
    assert runs[0] == runs[1]


def test_world_overrides_of_the_reference_variants():
    needs = {"queue_len": 1, "agent_order": "id"}
    assert world_overrides(["csaf-ref"]) == needs and POLICY_WORLD_OVERRIDES["csaf11-ref"] == needs
    assert world_overrides(["csaf11-ref", "csaf-ref", "csaf11-ref"]) == needs
    assert world_overrides(["formic", "csaf", "csaf11", "cardinality"]) == {}
    with pytest.raises(ValueError, match="csaf11-ref needs queue_len=1.*formic needs the scenario's own"):
        world_overrides(["csaf11-ref", "formic"])
    scenario = generate_scenario(WorldConfig(height=32, width=32, n_agents=8), seed=0)
    assert apply_world_overrides(scenario, ["csaf"]) is scenario
    changed = apply_world_overrides(scenario, ["csaf11-ref"])
    assert changed.config == scenario.config.replace(**needs) and changed.agents == scenario.agents
    assert Scenario.from_json(changed.to_json()).config.queue_len == 1  # stored and reloaded
    team = Team.parse("csaf11-ref:0-3,csaf-ref:4-7", 8)
    assert [name for name, _ in team.groups] == ["csaf11-ref", "csaf-ref"]


def test_runs_of_the_reference_variants_get_their_world(tmp_path, monkeypatch):
    from click.testing import CliRunner

    import formic_runtime.episode
    from formic_cli.main import cli
    from formic_eval import runner
    from formic_eval.matrix import PolicyOptions, Setting, generate_matrix, plan_tasks

    scenario = generate_scenario(WorldConfig(height=32, width=32, n_agents=4, episode_steps=20), seed=0)
    result = run_episode(scenario, "csaf11-ref")  # run_episode itself
    assert result.world.scenario.config.queue_len == 1 and result.world.config.agent_order == "id"
    assert run_episode(scenario, "csaf11").world.config.queue_len == 5

    matrix = generate_matrix([Setting(32, 4, 0.0, "infinite", 20)], 1, seed=0, directory=tmp_path / "set")
    (task,) = plan_tasks(matrix, ["csaf-ref"], PolicyOptions())
    ran = []

    def spy(scenario, *args, **kwargs):  # the scenario the runner hands over
        ran.append(scenario.config)
        return run_episode(scenario, *args, **kwargs)

    monkeypatch.setattr(formic_runtime.episode, "run_episode", spy)
    record = runner.run_task(task)
    monkeypatch.undo()
    assert [(c.queue_len, c.agent_order) for c in ran] == [(1, "id")]
    assert record["world_overrides"] == {"queue_len": 1, "agent_order": "id"}
    assert Scenario.load(task.scenario.path).config.queue_len == 5  # the stored file is untouched

    args = ["sim", "--size", "32", "--agents", "4", "--steps", "20", "--json", "--out", str(tmp_path / "sim")]
    out = CliRunner().invoke(cli, args + ["--policy", "csaf-ref"])
    assert out.exit_code == 0, out.output
    assert json.loads(out.output.strip().splitlines()[-1])["world_overrides"] == {"queue_len": 1, "agent_order": "id"}
    out = CliRunner().invoke(cli, args + ["--policy", "csaf-ref:0-1,formic:2-3"])
    assert out.exit_code != 0 and "cannot share one world" in out.output
