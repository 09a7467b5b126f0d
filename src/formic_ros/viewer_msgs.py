"""Messages for viewers (RViz, Foxglove): the sim clock, the map and the agents as markers.
One way only: nothing reads them back."""

from __future__ import annotations

import numpy as np
from builtin_interfaces.msg import Time
from geometry_msgs.msg import Point, Vector3
from nav_msgs.msg import MapMetaData, OccupancyGrid
from rosgraph_msgs.msg import Clock
from std_msgs.msg import ColorRGBA, Header
from visualization_msgs.msg import Marker, MarkerArray

from formic_world import World
from formic_world.geometry import CACHE, RESOURCE

from .wire import typed


def sim_time(step: int, dt: float) -> Time:
    nanos = int(round(step * dt * 1e9))
    return Time(sec=nanos // 1_000_000_000, nanosec=nanos % 1_000_000_000)


def clock(step: int, dt: float) -> Clock:
    return Clock(clock=sim_time(step, dt))


def occupancy_grid(world: World, stamp: Time, frame: str = "map") -> OccupancyGrid:
    """Grid and pheromone as an OccupancyGrid: free cells 0-60 by pheromone, resources 80,
    caches 90, obstacles 100. Map y grows northwards (row 0 is the top row), 1 m a cell."""
    height, width = world.grid.shape
    values = np.rint(np.clip(world.visible_pheromone(), 0.0, 1.0) * 60).astype(np.int8)
    values[world.grid == 1] = 100
    values[world.grid == RESOURCE] = 80
    values[world.grid == CACHE] = 90
    return OccupancyGrid(header=Header(stamp=stamp, frame_id=frame), data=typed("b", values[::-1], np.int8),
                         info=MapMetaData(map_load_time=stamp, resolution=1.0, width=width, height=height))


def _colour(r: float, g: float, b: float) -> ColorRGBA:
    return ColorRGBA(r=r, g=g, b=b, a=1.0)


def agent_markers(world: World, stamp: Time, frame: str = "map") -> MarkerArray:
    """Agents (orange when carrying, blue when empty) and resources (green) as cube lists."""
    height = world.grid.shape[0]
    empty, loaded, food = _colour(0.2, 0.4, 1.0), _colour(1.0, 0.55, 0.0), _colour(0.1, 0.8, 0.2)

    def cubes(marker_id: int, ns: str, cells: np.ndarray, colours: list[ColorRGBA]) -> Marker:
        points = [Point(x=float(c) + 0.5, y=float(height - 1 - r) + 0.5, z=0.5) for r, c in cells]
        return Marker(header=Header(stamp=stamp, frame_id=frame), ns=ns, id=marker_id, type=Marker.CUBE_LIST,
                      action=Marker.ADD, scale=Vector3(x=0.9, y=0.9, z=0.9), points=points, colors=colours)

    return MarkerArray(markers=[
        cubes(0, "agents", world.pos, [loaded if c else empty for c in world.carrying]),
        cubes(1, "resources", world.resource_pos, [food] * len(world.resource_pos)),
    ])
