"""The settings of the robot processes (``formic robot``, ``formic robots-sim``), without ROS:
the launcher writes them for its children (:mod:`formic_ros.launch.robots`). The defaults here are
the one set that ``formic run --robots``, ``formic robot`` and ``formic robots-sim`` share (and
docs/robots.md states)."""

from __future__ import annotations

from dataclasses import dataclass

from formic_robots.controller import ControllerSettings
from formic_robots.unicycle import UnicycleLimits

CMD_VEL = "/robot_{agent}/cmd_vel"  # topic templates ({agent}: the agent id)
ODOM = "/robot_{agent}/odom"
MAX_SPEED = 0.5  # m/s: the bridges' top speed (and the simulated robots')
MAX_TURN = 2.0  # rad/s
STALL_S = 3.0  # no progress for this long: the move fails (blocked)
ODOM_ORIGIN = "map"  # where the odometry frame lies in map: "map", "start" or "X,Y,YAW"
ROBOT_TOLERANCE = 0.1  # m from a cell's centre that count as in the cell (the world's)
ROBOT_CELL_S = 10.0  # s a robot gets per cell of a move (the world's)


def controller_settings(max_speed: float = MAX_SPEED, max_turn: float = MAX_TURN,
                        cell_size: float | None = None) -> ControllerSettings:
    """The bridges' go-to-cell controller at a top speed and turn rate: it plans to brake at 1.5
    times the top speed a second (3/4 of what a simulated robot can: it accelerates at twice) and
    stops on the spot; on a known cell size it passes a route's intermediate cells within a
    quarter cell."""
    extra = {} if cell_size is None else {"pass_radius": cell_size / 4}
    return ControllerSettings(max_linear=max_speed, max_angular=max_turn, linear_decel=1.5 * max_speed,
                              angular_decel=1.5 * max_turn, linear_gain=8.0, angular_gain=8.0, **extra)


@dataclass(frozen=True)
class BridgeSettings:
    cmd_vel: str = CMD_VEL
    odom: str = ODOM  # nav_msgs/Odometry
    pose: str | None = None  # geometry_msgs/PoseStamped instead of odometry (a localisation or tracking system)
    odom_origin: str = ODOM_ORIGIN
    stall_s: float = STALL_S
    controller: ControllerSettings = controller_settings()


@dataclass(frozen=True)
class SimSettings:
    cmd_vel: str = CMD_VEL
    odom: str = ODOM
    rate_hz: float = 50.0  # integration and publishing rate (the integration follows the wall clock)
    cell_size: float = 1.0  # the world's metric frame (formic world --cell-size, --map-origin)
    origin: tuple[float, float] = (0.0, 0.0)
    limits: UnicycleLimits = UnicycleLimits()
    seed: int = 0
