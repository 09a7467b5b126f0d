"""The map frame: cells to metres and back, with ROS's axes (x east, y north)."""

from __future__ import annotations

import math

import pytest

from formic_world.geometry import DIRECTION_DELTAS, EAST, NORTH, SOUTH, WEST
from formic_world.metric_frame import DIRECTION_YAWS, MetricFrame


def test_corners_and_axes():
    frame = MetricFrame(height=4, width=6, cell_size=0.5, origin_x=-1.0, origin_y=2.0)
    assert frame.cell_centre(3, 0) == (-0.75, 2.25)  # south-west cell touches the origin
    assert frame.cell_centre(0, 5) == (1.75, 3.75)  # north-east cell
    assert frame.cell_at(-1.0, 2.0) == (3, 0)
    assert frame.cell_at(1.99, 3.99) == (0, 5)
    assert frame.cell_at(2.0, 3.0) is None and frame.cell_at(0.0, 1.99) is None


@pytest.mark.parametrize("direction", [NORTH, EAST, SOUTH, WEST])
def test_move_directions_point_along_their_yaw(direction):
    frame = MetricFrame(height=8, width=8, cell_size=2.0)
    row, col = 4, 4
    dr, dc = DIRECTION_DELTAS[direction]
    (x0, y0), (x1, y1) = frame.cell_centre(row, col), frame.cell_centre(row + dr, col + dc)
    assert math.isclose(math.atan2(y1 - y0, x1 - x0), DIRECTION_YAWS[direction], abs_tol=1e-12)
    assert frame.distance_to_cell(x0, y0, row + dr, col + dc) == 2.0


def test_every_cell_round_trips():
    frame = MetricFrame(height=5, width=7, cell_size=0.3, origin_x=1.5, origin_y=-4.0)
    assert all(frame.cell_at(*frame.cell_centre(r, c)) == (r, c) for r in range(5) for c in range(7))


@pytest.mark.parametrize("size", [0.0, -1.0, math.inf, math.nan])
def test_cell_size_must_be_positive_metres(size):
    with pytest.raises(ValueError, match="cell_size"):
        MetricFrame(height=4, width=4, cell_size=size)
