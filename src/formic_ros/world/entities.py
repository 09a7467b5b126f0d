"""The world's entities as simulation_interfaces sees them: names, categories, tags and
ground-truth states in the ``map`` frame (:mod:`formic_world.metric_frame`), and the standard's
entity filters (name regex, categories, tags, bounds).

Entities: every agent (``agent_K``, a robot), every resource (``resource_I``, I its index in the
core, kept when a finite resource reappears elsewhere) and the four nest caches
(``nest_cache_nw``, ``_ne``, ``_sw``, ``_se``). An entity is its cell: a ``cell_size`` square
at z = 0 whose centre is the pose. An agent faces the direction of its last move (identity
orientation before its first move and while it queues); its twist and acceleration are zero,
as it jumps a whole cell per step. Obstacles are not entities (the ``map`` topic carries them).
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass

import numpy as np
from builtin_interfaces.msg import Time
from geometry_msgs.msg import Point, Pose, Quaternion
from simulation_interfaces.msg import Bounds, EntityCategory, EntityFilters, EntityInfo, EntityState, Result, TagsFilter
from std_msgs.msg import Header

from formic_world import World
from formic_world.geometry import nest_cache_cells
from formic_world.metric_frame import DIRECTION_YAWS, MAP_FRAME, MetricFrame

CACHE_NAMES = ("nw", "ne", "sw", "se")  # the core's queues 0-3


@dataclass(frozen=True)
class Entity:
    name: str
    category: int  # an EntityCategory constant
    tags: tuple[str, ...]
    description: str
    x: float  # centre of its cell in the map frame, metres
    y: float
    yaw: float  # radians, counter-clockwise from +x (east)


class FilterError(ValueError):
    """A filter the world cannot apply: ``code`` is the Result to answer with."""

    def __init__(self, code: int, message: str):
        super().__init__(message)
        self.code = code


def world_entities(world: World, frame: MetricFrame) -> list[Entity]:
    """Every entity of the world as it is now: agents, resources, nest caches."""
    entities = []
    for a, ((row, col), move) in enumerate(zip(world.pos.tolist(), world.last_move.tolist())):
        x, y = frame.cell_centre(row, col)
        carrying = "carrying" if world.load[a] > 0 else "empty"
        entities.append(Entity(f"agent_{a}", EntityCategory.CATEGORY_ROBOT, ("agent",), f"agent {a} ({carrying})",
                               x, y, DIRECTION_YAWS.get(move, 0.0)))
    finite = world.resource_capacity > 0
    for i, (row, col) in enumerate(world.resource_pos.tolist()):
        x, y = frame.cell_centre(row, col)
        if finite[i]:
            category, kind = EntityCategory.CATEGORY_OBJECT, "finite: reappears elsewhere when empty"
        else:
            category, kind = EntityCategory.CATEGORY_STATIC_OBJECT, "infinite"
        entities.append(Entity(f"resource_{i}", category, ("resource",), f"resource {i} ({kind})", x, y, 0.0))
    for name, (row, col) in zip(CACHE_NAMES, nest_cache_cells(world.config.height, world.config.width)):
        x, y = frame.cell_centre(row, col)
        entities.append(Entity(f"nest_cache_{name}", EntityCategory.CATEGORY_STATIC_OBJECT, ("nest", "cache"),
                               f"the nest's {name.upper()} cache", x, y, 0.0))
    return entities


def select(entities: list[Entity], filters: EntityFilters, cell_size: float) -> list[Entity]:
    """The entities that pass every filter given (the standard's EntityFilters); raises
    :class:`FilterError` for a filter that cannot be applied."""
    chosen = entities
    if filters.filter:
        try:
            pattern = re.compile(filters.filter)
        except re.error as exc:
            raise FilterError(Result.RESULT_OPERATION_FAILED, f"name filter {filters.filter!r}: {exc}") from exc
        chosen = [e for e in chosen if pattern.search(e.name)]
    if filters.categories:
        wanted = {c.category for c in filters.categories}
        chosen = [e for e in chosen if e.category in wanted]
    tags = filters.tags
    if tags.tags:
        wanted_tags = set(tags.tags)
        if tags.filter_mode == TagsFilter.FILTER_MODE_ALL:
            chosen = [e for e in chosen if wanted_tags <= set(e.tags)]
        elif tags.filter_mode == TagsFilter.FILTER_MODE_ANY:
            chosen = [e for e in chosen if wanted_tags & set(e.tags)]
        else:
            raise FilterError(Result.RESULT_OPERATION_FAILED, f"unknown tags filter_mode {tags.filter_mode}")
    if filters.bounds.type != Bounds.TYPE_EMPTY:
        overlaps = overlap_test(filters.bounds, cell_size / 2)
        chosen = [e for e in chosen if overlaps(e.x, e.y)]
    return chosen


def overlap_test(bounds: Bounds, half: float):
    """Whether the cell square centred at (x, y), z = 0, with half-side ``half`` overlaps the
    bounds (map frame): spheres and axis-aligned boxes; convex hulls are not supported."""
    points = [(p.x, p.y, p.z) for p in bounds.points]
    if bounds.type == Bounds.TYPE_SPHERE:
        if len(points) != 2 or points[1][0] < 0:
            raise FilterError(Result.RESULT_OPERATION_FAILED,
                              "a sphere is two points: the centre, then the radius in x (non-negative)")
        (cx, cy, cz), radius = points[0], points[1][0]

        def in_sphere(x: float, y: float) -> bool:
            dx = max(abs(cx - x) - half, 0.0)
            dy = max(abs(cy - y) - half, 0.0)
            return math.sqrt(dx * dx + dy * dy + cz * cz) <= radius

        return in_sphere
    if bounds.type == Bounds.TYPE_BOX:
        if len(points) != 2:
            raise FilterError(Result.RESULT_OPERATION_FAILED, "a box is two points: opposite corners")
        low, high = np.minimum(points[0], points[1]), np.maximum(points[0], points[1])

        def in_box(x: float, y: float) -> bool:
            return (x + half >= low[0] and x - half <= high[0] and y + half >= low[1] and y - half <= high[1]
                    and low[2] <= 0.0 <= high[2])

        return in_box
    if bounds.type == Bounds.TYPE_CONVEX_HULL:
        raise FilterError(Result.RESULT_FEATURE_UNSUPPORTED, "bounds of TYPE_CONVEX_HULL are not supported")
    raise FilterError(Result.RESULT_OPERATION_FAILED, f"unknown bounds type {bounds.type}")


def entity_state(entity: Entity, stamp: Time) -> EntityState:
    """The entity's pose in the map frame at sim time ``stamp``; zero twist and acceleration."""
    orientation = Quaternion(z=math.sin(entity.yaw / 2), w=math.cos(entity.yaw / 2))
    return EntityState(header=Header(stamp=stamp, frame_id=MAP_FRAME),
                       pose=Pose(position=Point(x=entity.x, y=entity.y, z=0.0), orientation=orientation))


def entity_info(entity: Entity) -> EntityInfo:
    return EntityInfo(category=EntityCategory(category=entity.category), description=entity.description,
                      tags=list(entity.tags))
