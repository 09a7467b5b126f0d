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


def test_viewer_map_and_markers_lie_in_the_frame_and_replay_checks_them_there():
    """The recorded map and agent markers use the world's cell size and origin (as entity poses
    and robots do); `formic replay --verify` reads the frame back from the map."""
    pytest.importorskip("rclpy")
    from builtin_interfaces.msg import Time

    from formic_record import checks
    from formic_ros.world import viewer_msgs
    from formic_world import make_world

    world = make_world(height=16, width=16, n_agents=4, seed=3)
    frame = MetricFrame(height=16, width=16, cell_size=0.5, origin_x=-2.0, origin_y=1.0)
    grid = viewer_msgs.occupancy_grid(world, Time(), frame)
    markers = viewer_msgs.agent_markers(world, Time(), frame)
    assert (grid.info.resolution, grid.info.origin.position.x, grid.info.origin.position.y) == (0.5, -2.0, 1.0)
    agents = next(m for m in markers.markers if m.ns == "agents")
    assert [(p.x, p.y) for p in agents.points] == [frame.cell_centre(r, c) for r, c in world.pos]
    assert agents.scale.x == pytest.approx(0.45)
    assert checks.check_map(grid, world) is None
    assert checks.check_markers(markers, world, checks.map_frame(grid, world)) is None
    assert "markers[agents].points" in checks.check_markers(markers, world)  # read in 1 m cells: wrong
