"""The grid in metres: the ``map`` frame that simulators, robots and tf share.

ROS conventions (REP 103, REP 105, ``nav_msgs/OccupancyGrid``): ``map`` is a right-handed frame
with x east and y north, in metres. The grid's lower-left corner (the outer corner of cell
``(height - 1, 0)``, south-west) sits at ``origin``; a cell is a square of ``cell_size`` metres
and its pose is its centre. Row indices grow southwards in the core (``geometry.DIRECTION_DELTAS``),
so row ``r`` spans ``y`` in ``[origin_y + (height - 1 - r) * s, origin_y + (height - r) * s)``:
the same layout as an ``OccupancyGrid`` whose data row ``i`` is the core's row ``height - 1 - i``.
The move NORTH is +y (yaw pi/2), EAST +x (yaw 0), SOUTH -y, WEST -x.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from .geometry import CACHE, EAST, NORTH, OBSTACLE, RESOURCE, SOUTH, WEST

if TYPE_CHECKING:
    from .world import World

MAP_FRAME = "map"

# yaw of each move direction in the map frame (radians, counter-clockwise from +x)
DIRECTION_YAWS = {EAST: 0.0, NORTH: math.pi / 2, WEST: math.pi, SOUTH: -math.pi / 2}


@dataclass(frozen=True)
class MetricFrame:
    """Where the grid of ``height`` x ``width`` cells lies in the ``map`` frame."""

    height: int
    width: int
    cell_size: float = 1.0  # metres per cell
    origin_x: float = 0.0  # map coordinates of the grid's south-west outer corner
    origin_y: float = 0.0

    def __post_init__(self) -> None:
        if not (self.cell_size > 0 and math.isfinite(self.cell_size)):
            raise ValueError(f"cell_size must be a positive number of metres, got {self.cell_size}")

    def cell_centre(self, row: int, col: int) -> tuple[float, float]:
        """The ``(x, y)`` of cell ``(row, col)``'s centre in metres."""
        return (self.origin_x + (col + 0.5) * self.cell_size,
                self.origin_y + (self.height - 1 - row + 0.5) * self.cell_size)

    def cell_at(self, x: float, y: float) -> tuple[int, int] | None:
        """The ``(row, col)`` of the cell containing point ``(x, y)``, or None off the grid."""
        col = math.floor((x - self.origin_x) / self.cell_size)
        row = self.height - 1 - math.floor((y - self.origin_y) / self.cell_size)
        if 0 <= row < self.height and 0 <= col < self.width:
            return row, col
        return None

    def distance_to_cell(self, x: float, y: float, row: int, col: int) -> float:
        """Metres from ``(x, y)`` to the centre of cell ``(row, col)``."""
        cx, cy = self.cell_centre(row, col)
        return math.hypot(cx - x, cy - y)


def occupancy_values(world: World) -> np.ndarray:
    """The world as ``OccupancyGrid`` data (int8, data row 0 the southern row): free cells 0-60
    by visible pheromone, resources 80, caches 90, obstacles 100. What the world node publishes
    on ``map`` and what ``formic replay --verify`` expects there."""
    values = np.rint(np.clip(world.visible_pheromone(), 0.0, 1.0) * 60).astype(np.int8)
    values[world.grid == OBSTACLE] = 100
    values[world.grid == RESOURCE] = 80
    values[world.grid == CACHE] = 90
    return values[::-1]
