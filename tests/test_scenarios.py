"""Scenario generation (SPEC §1) and the plain-JSON scenario files (SPEC §8)."""

from __future__ import annotations

import json

import numpy as np
import pytest
from conftest import agent, build_scenario, resource
from scipy import ndimage

from formic_world import Scenario, ScenarioError, World, WorldConfig, generate_scenario
from formic_world.config import resource_count_range
from formic_world.geometry import EAST, FREE, NEST_QUEUE_DIRECTIONS, SOUTH, nest_cache_cells, strip_cells
from formic_world.scenario import all_queue_cells, nearest_nest_cells, static_grid

SMALL = WorldConfig(height=32, width=32, n_agents=8)
LARGE = WorldConfig(height=128, width=128, n_agents=32)


def nest_strips(cfg: WorldConfig) -> list[np.ndarray]:
    return [
        strip_cells(cache, d, cfg.queue_len)
        for cache, d in zip(nest_cache_cells(cfg.height, cfg.width), NEST_QUEUE_DIRECTIONS)
    ]


def reserved_counts(scenario: Scenario) -> np.ndarray:
    """How many reserved strips (nest and resources) cover each cell."""
    cfg = scenario.config
    counts = np.zeros((cfg.height, cfg.width), dtype=int)
    strips = nest_strips(cfg) + [
        strip_cells((r.row, r.col), r.direction, cfg.queue_len) for r in scenario.resources
    ]
    for strip in strips:
        counts[strip[:, 0], strip[:, 1]] += 1
    return counts


def queues_reachable(scenario: Scenario) -> bool:
    cfg = scenario.config
    grid = static_grid(cfg, scenario.obstacles, scenario.resources)
    labels, _ = ndimage.label(grid == FREE)
    cells = all_queue_cells(cfg, scenario.resources)
    nest_label = labels[tuple(cells[0])]
    return nest_label > 0 and bool((labels[cells[:, 0], cells[:, 1]] == nest_label).all())


# --------------------------------------------------------------- resources


def test_resource_count_ranges():
    assert resource_count_range(32, 32) == (10, 10)
    assert resource_count_range(64, 64) == (10, 26)
    assert resource_count_range(128, 128) == (35, 106)


def test_small_world_has_ten_resources():
    for seed in range(5):
        assert len(generate_scenario(SMALL, seed).resources) == 10


def test_large_world_resource_count_is_drawn_in_range():
    counts = {len(generate_scenario(LARGE, seed).resources) for seed in range(12)}
    assert all(35 <= c <= 106 for c in counts)
    assert len(counts) >= 6  # drawn, not fixed


@pytest.mark.parametrize("cfg", [SMALL, LARGE, SMALL.replace(obstacle_density=0.05)])
def test_strips_are_disjoint_and_off_the_outer_ring(cfg):
    directions = set()
    for seed in range(4):
        scenario = generate_scenario(cfg, seed)
        assert reserved_counts(scenario).max() == 1
        for r in scenario.resources:
            strip = strip_cells((r.row, r.col), r.direction, cfg.queue_len)
            assert strip.min() >= 1
            assert strip[:, 0].max() <= cfg.height - 2 and strip[:, 1].max() <= cfg.width - 2
            directions.add(r.direction)
            assert r.capacity == 0  # infinite by default
    assert directions == {0, 1, 2, 3}  # west included (the reference could never pick it)


def test_finite_capacities_are_drawn_in_4_8():
    capacities = set()
    for seed in range(3):
        scenario = generate_scenario(SMALL.replace(capacity="finite"), seed)
        capacities |= {r.capacity for r in scenario.resources}
    assert capacities <= set(range(4, 9)) and len(capacities) >= 3


# --------------------------------------------------------------- obstacles


@pytest.mark.parametrize("cfg, count", [(SMALL, 51), (LARGE, 819)])
def test_obstacles_count_placement_and_reachability(cfg, count):
    cfg = cfg.replace(obstacle_density=0.05)
    for seed in range(3):
        scenario = generate_scenario(cfg, seed)
        obstacles = np.array(scenario.obstacles)
        assert len(obstacles) == count == round(0.05 * cfg.height * cfg.width)
        assert len({tuple(o) for o in obstacles}) == count
        assert (obstacles >= 0).all() and (obstacles[:, 0] < cfg.height).all()
        assert (reserved_counts(scenario)[obstacles[:, 0], obstacles[:, 1]] == 0).all()
        assert queues_reachable(scenario)


def test_no_obstacles_at_density_zero():
    assert generate_scenario(SMALL, 0).obstacles == ()


# ------------------------------------------------------------------ agents


def test_nearest_nest_cells_fill_the_smallest_centred_square():
    # 16x16: the 4x4 square around the nest holds 4 caches and 4 cache-queue spots 0, so
    # exactly 8 free cells: the 4 edge-adjacent ones first, then the corners (row, col order)
    free = np.ones((16, 16), dtype=bool)
    for cell in nest_cache_cells(16, 16) + [(7, 6), (6, 8), (9, 7), (8, 9)]:
        free[cell] = False
    assert nearest_nest_cells(free, 8) == [
        (6, 7), (7, 9), (8, 6), (9, 8), (6, 6), (6, 9), (9, 6), (9, 9),
    ]
    ninth = nearest_nest_cells(free, 9)[8]
    assert max(abs(ninth[0] - 7.5), abs(ninth[1] - 7.5)) == 2.5
    with pytest.raises(ScenarioError, match="no room"):
        nearest_nest_cells(free, 16 * 16)


@pytest.mark.parametrize("n_agents", [8, 64])
def test_agents_start_empty_on_the_free_cells_nearest_the_nest(n_agents):
    cfg = SMALL.replace(n_agents=n_agents, obstacle_density=0.05)
    scenario = generate_scenario(cfg, 3)
    grid = static_grid(cfg, scenario.obstacles, scenario.resources)
    free = grid == FREE
    queue = all_queue_cells(cfg, scenario.resources)
    free[queue[:, 0], queue[:, 1]] = False  # interpretation: nobody starts inside a queue
    rows, cols = np.nonzero(free)
    ring = np.maximum(np.abs(rows - 15.5), np.abs(cols - 15.5))
    starts = {(a.row, a.col) for a in scenario.agents}
    assert len(starts) == n_agents
    assert all(not a.loaded and a.cache_queue == -1 for a in scenario.agents)
    chosen = np.array([(r, c) in starts for r, c in zip(rows, cols)])
    assert chosen.sum() == n_agents  # all on free, non-queue cells
    assert ring[chosen].max() <= ring[~chosen].min()  # the smallest centred square first


def test_training_start_puts_loaded_agents_in_cache_queues():
    cfg = SMALL.replace(n_agents=32, training_start=True)
    counts = []
    for seed in range(12):
        scenario = generate_scenario(cfg, seed)
        queued = [a for a in scenario.agents if a.cache_queue >= 0]
        counts.append(len(queued))
        assert 0 <= len(queued) <= 20
        assert all(a.loaded for a in queued)
        assert all(not a.loaded for a in scenario.agents if a.cache_queue < 0)
        world = World(scenario)
        ids = [i for i, a in enumerate(scenario.agents) if a.cache_queue >= 0]
        assert world.queued[ids].all() and (world.load[ids] == world.load_full).all()
        assert world.queue_count[:4].sum() == len(queued)
        for q in range(4):  # each cache queue is filled from spot 0 without gaps
            members = world.queue_members[q]
            assert (members[: world.queue_count[q]] >= 0).all() and (members[world.queue_count[q]:] == -1).all()
    assert len(set(counts)) >= 4 and max(counts) > 0


def test_training_start_never_queues_more_agents_than_the_team():
    for seed in range(10):
        scenario = generate_scenario(SMALL.replace(n_agents=3, training_start=True), seed)
        assert sum(a.cache_queue >= 0 for a in scenario.agents) <= 3


# ---------------------------------------------------------------- wipeouts


def test_wipeouts_do_not_overlap_and_fit_the_episode():
    cfg = SMALL.replace(wipeouts=3)
    seen = set()
    for seed in range(10):
        starts = generate_scenario(cfg, seed).wipeout_starts
        assert len(starts) == 3 and list(starts) == sorted(starts)
        assert all(b - a >= 100 for a, b in zip(starts, starts[1:]))
        assert starts[0] >= 0 and starts[-1] + 100 <= 512
        seen.add(starts)
    assert len(seen) == 10


# ------------------------------------------------------------ files, seeds


@pytest.mark.parametrize(
    "cfg",
    [SMALL, SMALL.replace(capacity="finite", obstacle_density=0.05, wipeouts=3), LARGE.replace(training_start=True)],
)
def test_save_load_round_trip(tmp_path, cfg):
    scenario = generate_scenario(cfg, 11)
    path = tmp_path / "nested" / "scenario.json"
    scenario.save(path)
    loaded = Scenario.load(path)
    assert loaded == scenario
    assert loaded.to_json() == scenario.to_json() == path.read_text()
    assert World(loaded).state_digest() == World(scenario).state_digest()
    json.loads(path.read_text())  # plain JSON
    assert list(tmp_path.joinpath("nested").iterdir()) == [path]  # no temporary left behind


def test_hand_built_scenario_round_trips():
    scenario = build_scenario(
        [agent(7, 6, True, 0), agent(2, 2)], resources=[resource(1, 10, SOUTH, 3)], obstacles=[(3, 3)]
    )
    assert Scenario.from_json(scenario.to_json()) == scenario


@pytest.mark.parametrize("cfg", [SMALL, LARGE.replace(obstacle_density=0.05, capacity="finite")])
def test_regenerate_is_bit_identical(cfg):
    scenario = generate_scenario(cfg, 5)
    again = Scenario.from_json(scenario.to_json()).regenerate()
    assert again == scenario and again.to_json() == scenario.to_json()
    assert generate_scenario(cfg, 6) != scenario


# ------------------------------------------------------------------ errors


def scenario_dict() -> dict:
    return generate_scenario(SMALL, 0).to_dict()


def write(tmp_path, text: str):
    path = tmp_path / "bad.json"
    path.write_text(text)
    return path


def test_corrupted_json_is_rejected(tmp_path):
    text = generate_scenario(SMALL, 0).to_json()
    path = write(tmp_path, text[: len(text) // 2])
    with pytest.raises(ScenarioError, match=r"bad\.json: scenario is not valid JSON"):
        Scenario.load(path)
    path.write_bytes(b"\xff\xfe\x00garbage")
    with pytest.raises(ScenarioError, match="not a text file"):
        Scenario.load(path)


@pytest.mark.parametrize(
    "change, message",
    [
        (lambda d: d.update(format="something-else"), "not a ForMIC scenario"),
        (lambda d: d.pop("format"), "not a ForMIC scenario"),
        (lambda d: d.update(version=3), "version 3 is not supported"),
            (lambda d: d.update(version=1), "version 1 scenario has no timing"),
        (lambda d: d.pop("agents"), "malformed scenario"),
        (lambda d: d["config"].update(height=5), "malformed scenario.*at least 15x15"),
        (lambda d: d["config"].update(colour="red"), "malformed scenario.*unknown world configuration"),
        (lambda d: d["obstacles"].append([40, 3]), r"obstacle \(40, 3\) is outside the 32x32 world"),
        (lambda d: d["obstacles"].append([3, -1]), r"obstacle \(3, -1\) is outside"),
        (lambda d: d["agents"][0].__setitem__(0, 32), "agent 0 starts on a blocked or outside cell"),
        (lambda d: d["resources"].append([30, 30, EAST, 0]), r"resource 10: its queue leaves the world"),
        (lambda d: d["resources"].append([30, 30, 7, 0]), "direction 7 is not 0-3"),
        (lambda d: d["resources"].__setitem__(0, d["resources"][0][:3] + [5]), "does not match mode"),
        (lambda d: d["agents"].pop(), "7 agent starts for n_agents=8"),
        (lambda d: d.update(wipeout_starts=[500]), "wipeout start 500 does not fit"),
    ],
)
def test_invalid_scenarios_are_rejected_with_a_reason(tmp_path, change, message):
    data = scenario_dict()
    change(data)
    with pytest.raises(ScenarioError, match=message):
        Scenario.load(write(tmp_path, json.dumps(data)))


@pytest.mark.parametrize("field, limit", [("height", 2048), ("width", 2048), ("n_agents", 65_536),
                                          ("view_size", 63), ("episode_steps", 1_000_000), ("queue_len", 64)])
def test_a_world_over_a_limit_is_refused_naming_field_value_and_limit(field, limit):
    WorldConfig(**{field: limit})
    with pytest.raises(ValueError) as refusal:
        WorldConfig(**{field: limit + 2})
    assert str(refusal.value) == f"{field} {limit + 2} is over the limit of {limit}"


def test_a_scenario_over_a_limit_is_refused_before_its_layout_is_read(tmp_path):
    data = scenario_dict()
    data["config"]["height"] = 1_000_000
    data["agents"] = "not read"  # the configuration is checked first
    with pytest.raises(ScenarioError) as refusal:
        Scenario.load(write(tmp_path, json.dumps(data)))
    assert str(refusal.value).endswith(": malformed scenario: height 1000000 is over the limit of 2048")


def test_non_object_json_is_rejected():
    with pytest.raises(ScenarioError, match="must be a JSON object"):
        Scenario.from_json("[1, 2, 3]")


def test_overlapping_queues_are_rejected():
    # two resources whose queues cross at (4,4)
    data = scenario_dict()
    data["resources"] = [[4, 1, EAST, 0], [1, 4, SOUTH, 0]]
    with pytest.raises(ScenarioError, match="share a queue cell"):
        Scenario.from_dict(data)


def test_version_1_files_load_with_the_nominal_timing_they_were_written_under(tmp_path):
    data = scenario_dict()
    assert data["version"] == 2 and data["config"]["timing"] == "reference"
    data["version"] = 1
    del data["config"]["timing"]
    scenario = Scenario.load(write(tmp_path, json.dumps(data)))
    assert scenario.config.timing == "nominal"
    assert scenario.to_dict()["version"] == 2 and scenario.to_dict()["config"]["timing"] == "nominal"
