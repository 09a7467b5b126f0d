"""Scenarios: a world's layout, generated from a seed and stored as plain versioned JSON.

A scenario holds everything a reset needs (configuration, obstacles, resources, agent starts,
wipeout times). ``generate_scenario(config, seed)`` is a pure function, so a stored scenario
can always be checked against a fresh regeneration from its seed.
"""

from __future__ import annotations

import json
import os
from collections.abc import Iterable
from dataclasses import dataclass
from typing import Any

import numpy as np

from .config import WorldConfig, resource_count_range
from .errors import InputError
from .files import atomic_open
from .geometry import (
    CACHE,
    FREE,
    NEST_QUEUE_DIRECTIONS,
    OBSTACLE,
    RESOURCE,
    nest_cache_cells,
    nest_centre,
    queue_cells,
    strip_cells,
)
from .limits import MAX_SCENARIO_BYTES

SCENARIO_FORMAT = "formic-scenario"
SCENARIO_VERSION = 2  # 2: the configuration carries ``timing``; version 1 files ran nominal timing
_PLACEMENT_TRIES = 200  # per resource strip before the whole layout is redrawn
_LAYOUT_TRIES = 100


class ScenarioError(InputError):
    """A scenario file or layout that cannot be used, with the reason."""


@dataclass(frozen=True)
class ResourceSpec:
    row: int
    col: int
    direction: int  # the way its queue runs from the resource cell
    capacity: int  # units; 0 means infinite


@dataclass(frozen=True)
class AgentStart:
    row: int
    col: int
    loaded: bool  # starts carrying one full unit
    cache_queue: int  # -1: free; 0-3: queued at that nest cache (training starts)


@dataclass(frozen=True)
class Scenario:
    config: WorldConfig
    seed: int
    obstacles: tuple[tuple[int, int], ...]
    resources: tuple[ResourceSpec, ...]
    agents: tuple[AgentStart, ...]
    wipeout_starts: tuple[int, ...]

    def to_dict(self) -> dict[str, Any]:
        return {
            "format": SCENARIO_FORMAT,
            "version": SCENARIO_VERSION,
            "seed": self.seed,
            "config": self.config.to_dict(),
            "obstacles": [list(o) for o in self.obstacles],
            "resources": [[r.row, r.col, r.direction, r.capacity] for r in self.resources],
            "agents": [[a.row, a.col, int(a.loaded), a.cache_queue] for a in self.agents],
            "wipeout_starts": list(self.wipeout_starts),
        }

    def to_json(self) -> str:
        return json.dumps(self.to_dict(), separators=(",", ":"))

    @classmethod
    def from_dict(cls, data: Any) -> "Scenario":
        if not isinstance(data, dict):
            raise ScenarioError("scenario must be a JSON object")
        if data.get("format") != SCENARIO_FORMAT:
            raise ScenarioError(f"not a ForMIC scenario (format={data.get('format')!r})")
        version = data.get("version")
        if version not in (1, SCENARIO_VERSION):
            raise ScenarioError(
                f"scenario version {version!r} is not supported (expected 1 or {SCENARIO_VERSION})"
            )
        try:
            config_data = data["config"]
            if version == 1:
                if not isinstance(config_data, dict) or "timing" in config_data:
                    raise ScenarioError("a version 1 scenario has no timing in its configuration")
                config_data = {**config_data, "timing": "nominal"}  # the only rule version 1 knew
            config = WorldConfig.from_dict(config_data)
            scenario = cls(
                config=config,
                seed=int(data["seed"]),
                obstacles=tuple((int(r), int(c)) for r, c in data["obstacles"]),
                resources=tuple(
                    ResourceSpec(int(r), int(c), int(d), int(k)) for r, c, d, k in data["resources"]
                ),
                agents=tuple(
                    AgentStart(int(r), int(c), bool(loaded), int(q)) for r, c, loaded, q in data["agents"]
                ),
                wipeout_starts=tuple(int(s) for s in data["wipeout_starts"]),
            )
        except ScenarioError:
            raise
        except KeyError as exc:
            raise ScenarioError(f"malformed scenario: no {exc.args[0]!r} field") from exc
        except (TypeError, ValueError) as exc:
            raise ScenarioError(f"malformed scenario: {exc}") from exc
        validate_scenario(scenario)
        return scenario

    @classmethod
    def from_json(cls, text: str) -> "Scenario":
        try:
            data = json.loads(text)
        except json.JSONDecodeError as exc:
            raise ScenarioError(f"scenario is not valid JSON: {exc}") from exc
        return cls.from_dict(data)

    def save(self, path: str | os.PathLike) -> None:
        """Write atomically: a crash leaves the old file or the new one, never half of one."""
        with atomic_open(path) as handle:
            handle.write(self.to_json())

    @classmethod
    def load(cls, path: str | os.PathLike) -> "Scenario":
        """Read a scenario file; one larger than MAX_SCENARIO_BYTES is refused unread."""
        try:
            with open(path, "rb") as handle:
                size = os.fstat(handle.fileno()).st_size
                if size > MAX_SCENARIO_BYTES:
                    raise ScenarioError(f"{path}: {size:,} bytes is over the limit of {MAX_SCENARIO_BYTES:,} "
                                        "for a scenario file")
                text = handle.read().decode()
        except UnicodeDecodeError as exc:
            raise ScenarioError(f"{path}: not a text file") from exc
        except OSError as exc:
            raise ScenarioError(f"{path}: cannot read ({exc.strerror})") from exc
        try:
            return cls.from_json(text)
        except ScenarioError as exc:
            raise ScenarioError(f"{path}: {exc}") from exc

    def regenerate(self) -> "Scenario":
        return generate_scenario(self.config, self.seed)


def _layout_cells(cells_of, config: WorldConfig, resources: Iterable[ResourceSpec]) -> np.ndarray:
    """``cells_of(anchor, direction, queue_len)`` for the nest caches, then ``resources``, stacked."""
    anchors = list(zip(nest_cache_cells(config.height, config.width), NEST_QUEUE_DIRECTIONS))
    anchors += [((r.row, r.col), r.direction) for r in resources]
    return np.concatenate([cells_of(anchor, d, config.queue_len) for anchor, d in anchors])


def all_queue_cells(config: WorldConfig, resources: Iterable[ResourceSpec]) -> np.ndarray:
    """Every queue cell of the nest and of the given resources, shape (k, 2), queue by queue."""
    return _layout_cells(queue_cells, config, resources)


def reserved_cells(config: WorldConfig, resources: Iterable[ResourceSpec]) -> np.ndarray:
    """Mask of the reserved strips (SPEC §1) of the nest and of the given resources."""
    cells = _layout_cells(strip_cells, config, resources)
    reserved = np.zeros((config.height, config.width), dtype=bool)
    reserved[cells[:, 0], cells[:, 1]] = True
    return reserved


def find_resource_strip(
    rng: np.random.Generator, forbidden: np.ndarray, queue_len: int
) -> tuple[int, int, int] | None:
    """Draw a resource cell and queue direction whose strip avoids ``forbidden`` cells.

    The whole strip stays off the outer ring. Returns (row, col, direction) or None after
    a bounded number of tries.
    """
    height, width = forbidden.shape
    for _ in range(_PLACEMENT_TRIES):
        row = int(rng.integers(1, height - 1))
        col = int(rng.integers(1, width - 1))
        direction = int(rng.integers(0, 4))
        strip = strip_cells((row, col), direction, queue_len)
        if strip.min() < 1 or strip[:, 0].max() > height - 2 or strip[:, 1].max() > width - 2:
            continue
        if forbidden[strip[:, 0], strip[:, 1]].any():
            continue
        return row, col, direction
    return None


def passable_component_reaches(passable: np.ndarray, source: tuple[int, int], targets: np.ndarray) -> bool:
    """True if every target cell is connected to ``source`` through passable cells (4-connected)."""
    from scipy import ndimage  # here: processes that only read scenarios (agent hosts) skip scipy's start-up

    labels, _ = ndimage.label(passable)
    source_label = labels[source]
    return source_label != 0 and bool((labels[targets[:, 0], targets[:, 1]] == source_label).all())


def static_grid(config: WorldConfig, obstacles, resources) -> np.ndarray:
    """Cell kinds (FREE/OBSTACLE/RESOURCE/CACHE) of a layout."""
    grid = np.full((config.height, config.width), FREE, dtype=np.int8)
    for r, c in nest_cache_cells(config.height, config.width):
        grid[r, c] = CACHE
    for r, c in obstacles:
        grid[r, c] = OBSTACLE
    for res in resources:
        grid[res.row, res.col] = RESOURCE
    return grid


def _draw_resources(config: WorldConfig, rng: np.random.Generator) -> list[ResourceSpec] | None:
    lo, hi = resource_count_range(config.height, config.width)
    count = int(rng.integers(lo, hi + 1))
    forbidden = reserved_cells(config, [])
    resources = []
    for _ in range(count):
        placed = find_resource_strip(rng, forbidden, config.queue_len)
        if placed is None:
            return None
        row, col, direction = placed
        strip = strip_cells((row, col), direction, config.queue_len)
        forbidden[strip[:, 0], strip[:, 1]] = True
        capacity = 0
        if config.capacity == "finite":
            capacity = int(rng.integers(config.capacity_min, config.capacity_max + 1))
        resources.append(ResourceSpec(row, col, direction, capacity))
    return resources


def _draw_obstacles(
    config: WorldConfig, rng: np.random.Generator, resources: list[ResourceSpec]
) -> list[tuple[int, int]] | None:
    count = int(round(config.obstacle_density * config.height * config.width))
    if count == 0:
        return []
    candidates = np.flatnonzero(~reserved_cells(config, resources))
    if len(candidates) < count:
        return None
    chosen = np.sort(rng.choice(candidates, size=count, replace=False))
    obstacles = [(int(i // config.width), int(i % config.width)) for i in chosen]
    grid = static_grid(config, obstacles, resources)
    targets = all_queue_cells(config, resources)
    if not passable_component_reaches(grid == FREE, tuple(targets[0]), targets):
        return None
    return obstacles


def nearest_nest_cells(free: np.ndarray, count: int) -> list[tuple[int, int]]:
    """The ``count`` free cells nearest the nest centre: smallest centred square first."""
    height, width = free.shape
    cr, cc = nest_centre(height, width)
    rows, cols = np.nonzero(free)
    chebyshev = np.maximum(np.abs(rows - cr), np.abs(cols - cc))
    euclid = (rows - cr) ** 2 + (cols - cc) ** 2
    order = np.lexsort((cols, rows, euclid, chebyshev))[:count]
    if len(order) < count:
        raise ScenarioError(f"no room for {count} agents: a {height}x{width} world has {len(order)} free "
                            "cells to start on")
    return [(int(rows[i]), int(cols[i])) for i in order]


def _draw_agents(
    config: WorldConfig, rng: np.random.Generator, obstacles, resources
) -> list[AgentStart]:
    n = config.n_agents
    queued: list[AgentStart] = []
    if config.training_start:
        k = int(rng.integers(0, min(config.training_start_max_queued, n, 4 * config.queue_len) + 1))
        fill = [0, 0, 0, 0]
        caches = nest_cache_cells(config.height, config.width)
        for _ in range(k):
            open_queues = [q for q in range(4) if fill[q] < config.queue_len]
            q = open_queues[int(rng.integers(0, len(open_queues)))]
            cell = queue_cells(caches[q], NEST_QUEUE_DIRECTIONS[q], config.queue_len)[fill[q]]
            queued.append(AgentStart(int(cell[0]), int(cell[1]), True, q))
            fill[q] += 1
    free = static_grid(config, obstacles, resources) == FREE
    cells = all_queue_cells(config, resources)
    free[cells[:, 0], cells[:, 1]] = False  # never start anyone standing in a queue
    starts = nearest_nest_cells(free, n - len(queued))
    return [AgentStart(r, c, False, -1) for r, c in starts] + queued


def draw_wipeout_starts(config: WorldConfig, seed: int) -> tuple[int, ...]:
    """K non-overlapping windows of ``wipeout_steps`` inside the episode, from the seed."""
    if config.wipeouts == 0:
        return ()
    rng = np.random.default_rng([seed, 7])
    slack = config.episode_steps - config.wipeouts * config.wipeout_steps
    offsets = np.sort(rng.integers(0, slack + 1, size=config.wipeouts))
    return tuple(int(o + i * config.wipeout_steps) for i, o in enumerate(offsets))


def generate_scenario(config: WorldConfig, seed: int) -> Scenario:
    """Draw a layout for ``config`` from ``seed`` (pure: same inputs, same scenario)."""
    rng = np.random.default_rng(seed)
    for _ in range(_LAYOUT_TRIES):
        resources = _draw_resources(config, rng)
        if resources is None:
            continue
        obstacles = _draw_obstacles(config, rng, resources)
        if obstacles is None:
            continue
        agents = _draw_agents(config, rng, obstacles, resources)
        return Scenario(
            config=config,
            seed=seed,
            obstacles=tuple(obstacles),
            resources=tuple(resources),
            agents=tuple(agents),
            wipeout_starts=draw_wipeout_starts(config, seed),
        )
    raise ScenarioError(
        f"could not lay out a {config.height}x{config.width} world with seed {seed} "
        f"after {_LAYOUT_TRIES} tries"
    )


def validate_scenario(scenario: Scenario) -> None:
    """Reject layouts the world cannot run, with the first reason found."""
    cfg = scenario.config
    height, width = cfg.height, cfg.width

    def inside(r: int, c: int) -> bool:
        return 0 <= r < height and 0 <= c < width

    caches = nest_cache_cells(height, width)
    occupied = np.zeros((height, width), dtype=bool)
    for cache in caches:
        occupied[cache] = True
    for r, c in scenario.obstacles:
        if not inside(r, c):
            raise ScenarioError(f"obstacle ({r}, {c}) is outside the {height}x{width} world")
        if (r, c) in caches:
            raise ScenarioError(f"obstacle ({r}, {c}) covers a nest cache")
        occupied[r, c] = True
    for i, res in enumerate(scenario.resources):
        if res.direction not in (0, 1, 2, 3):
            raise ScenarioError(f"resource {i}: direction {res.direction} is not 0-3")
        if res.capacity < 0 or (cfg.capacity == "finite") != (res.capacity > 0):
            raise ScenarioError(f"resource {i}: capacity {res.capacity} does not match mode {cfg.capacity}")
        cells = strip_cells((res.row, res.col), res.direction, cfg.queue_len)[:-1]
        for r, c in cells:
            if not inside(r, c):
                raise ScenarioError(f"resource {i}: its queue leaves the world at ({r}, {c})")
        if occupied[cells[:, 0], cells[:, 1]].any():
            raise ScenarioError(f"resource {i} at ({res.row}, {res.col}) overlaps another cell in use")
        occupied[res.row, res.col] = True
    queue = all_queue_cells(cfg, scenario.resources)
    if occupied[queue[:, 0], queue[:, 1]].any():
        raise ScenarioError("a queue cell is blocked")
    if len(np.unique(queue, axis=0)) != len(queue):
        raise ScenarioError("two queues share a queue cell")
    if len(scenario.agents) != cfg.n_agents:
        raise ScenarioError(f"{len(scenario.agents)} agent starts for n_agents={cfg.n_agents}")
    seen = set()
    for i, agent in enumerate(scenario.agents):
        if not inside(agent.row, agent.col) or occupied[agent.row, agent.col]:
            raise ScenarioError(f"agent {i} starts on a blocked or outside cell ({agent.row}, {agent.col})")
        if (agent.row, agent.col) in seen:
            raise ScenarioError(f"agent {i} shares its start cell with another agent")
        seen.add((agent.row, agent.col))
        if agent.cache_queue not in (-1, 0, 1, 2, 3):
            raise ScenarioError(f"agent {i}: cache_queue {agent.cache_queue} is not -1 or 0-3")
    previous_end = 0
    for s in sorted(scenario.wipeout_starts):
        if not 0 <= s <= cfg.episode_steps - cfg.wipeout_steps:
            raise ScenarioError(f"wipeout start {s} does not fit in the episode")
        if s < previous_end:
            raise ScenarioError(f"wipeout starting at {s} overlaps the previous one")
        previous_end = s + cfg.wipeout_steps
