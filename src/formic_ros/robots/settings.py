"""The settings of the robot processes (``formic robot``, ``formic robots-sim``), without ROS:
the launcher writes them for its children (:mod:`formic_ros.launch.robots`)."""

from __future__ import annotations

from dataclasses import dataclass

from formic_robots.controller import ControllerSettings
from formic_robots.unicycle import UnicycleLimits


@dataclass(frozen=True)
class BridgeSettings:
    cmd_vel: str = "/robot_{agent}/cmd_vel"  # topic templates ({agent}: the agent id)
    odom: str = "/robot_{agent}/odom"  # nav_msgs/Odometry
    pose: str | None = None  # geometry_msgs/PoseStamped instead of odometry (a localisation or tracking system)
    odom_origin: str = "map"  # where the pose's frame lies in map: "map" (it is map), "start", or "X,Y,YAW"
    stall_s: float = 3.0  # no progress for this long: FAILED (blocked)
    controller: ControllerSettings = ControllerSettings()


@dataclass(frozen=True)
class SimSettings:
    cmd_vel: str = "/robot_{agent}/cmd_vel"  # topic templates ({agent}: the agent id)
    odom: str = "/robot_{agent}/odom"
    rate_hz: float = 50.0  # integration and publishing rate (the integration follows the wall clock)
    cell_size: float = 1.0  # the world's metric frame (formic world --cell-size, --map-origin)
    origin: tuple[float, float] = (0.0, 0.0)
    limits: UnicycleLimits = UnicycleLimits()
    seed: int = 0
