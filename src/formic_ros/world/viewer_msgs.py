"""Messages for viewers (RViz, Foxglove): the sim clock, the map and the agents as markers.
One way only: nothing reads them back."""

from __future__ import annotations

import numpy as np
from builtin_interfaces.msg import Time
from geometry_msgs.msg import Point, Pose, Vector3
from nav_msgs.msg import MapMetaData, OccupancyGrid
from rosgraph_msgs.msg import Clock
from std_msgs.msg import ColorRGBA, Header
from visualization_msgs.msg import Marker, MarkerArray

from formic_world import World
from formic_world.metric_frame import MAP_FRAME, MetricFrame, occupancy_values

from ..wire import typed


def sim_time(step: int, dt: float) -> Time:
    nanos = int(round(step * dt * 1e9))
    return Time(sec=nanos // 1_000_000_000, nanosec=nanos % 1_000_000_000)


def clock(step: int, dt: float) -> Clock:
    return Clock(clock=sim_time(step, dt))


def occupancy_grid(world: World, stamp: Time, frame: MetricFrame) -> OccupancyGrid:
    """Grid and pheromone as an OccupancyGrid in the ``map`` frame (``frame``'s cell size and
    origin; data row 0 is the southern row): free cells 0-60 by pheromone, resources 80,
    caches 90, obstacles 100."""
    height, width = world.grid.shape
    origin = Pose(position=Point(x=frame.origin_x, y=frame.origin_y))
    data = typed("b", occupancy_values(world), np.int8)
    return OccupancyGrid(header=Header(stamp=stamp, frame_id=MAP_FRAME), data=data,
                         info=MapMetaData(map_load_time=stamp, resolution=frame.cell_size, width=width,
                                          height=height, origin=origin))


def _colour(r: float, g: float, b: float) -> ColorRGBA:
    return ColorRGBA(r=r, g=g, b=b, a=1.0)


def agent_markers(world: World, stamp: Time, frame: MetricFrame) -> MarkerArray:
    """Agents (orange when carrying, blue when empty) and resources (green) as cube lists at
    their cells' centres in the ``map`` frame."""
    empty, loaded, food = _colour(0.2, 0.4, 1.0), _colour(1.0, 0.55, 0.0), _colour(0.1, 0.8, 0.2)
    side = 0.9 * frame.cell_size

    def cubes(marker_id: int, ns: str, cells: np.ndarray, colours: list[ColorRGBA]) -> Marker:
        points = [Point(x=x, y=y, z=side / 2) for x, y in (frame.cell_centre(int(r), int(c)) for r, c in cells)]
        return Marker(header=Header(stamp=stamp, frame_id=MAP_FRAME), ns=ns, id=marker_id, type=Marker.CUBE_LIST,
                      action=Marker.ADD, scale=Vector3(x=side, y=side, z=side), points=points, colors=colours)

    return MarkerArray(markers=[
        cubes(0, "agents", world.pos, [loaded if c else empty for c in world.carrying]),
        cubes(1, "resources", world.resource_pos, [food] * len(world.resource_pos)),
    ])
