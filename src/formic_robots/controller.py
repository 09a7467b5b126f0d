"""The go-to-cell controller: a differential-drive (unicycle) robot's velocity command that takes
it through a list of waypoints (cell centres) and stops on the last within a tolerance.

Turn on the spot while the target is far off the heading, then drive with a proportional
heading correction, slowing as the heading error grows and as the waypoint nears (routes turn
at waypoints): speed and turn rate follow a braking profile (``sqrt(2 a d)``) far away and a
proportional law close by, so the robot stops on the spot instead of creeping up to it. Passing
a waypoint needs no stop: it counts as reached within ``pass_radius``. Every command respects the
speed limits, so the robot's own acceleration limits are the only thing between command and motion.
"""

from __future__ import annotations

import math
from dataclasses import dataclass


@dataclass(frozen=True)
class ControllerSettings:
    max_linear: float = 0.5  # m/s
    max_angular: float = 2.0  # rad/s
    linear_gain: float = 4.0  # 1/s: speed per metre left, close to the waypoint
    angular_gain: float = 4.0  # 1/s: turn rate per radian of heading error, close to the heading
    linear_decel: float = 1.0  # m/s^2: braking planned for (at most the robot's own)
    angular_decel: float = 4.0  # rad/s^2
    turn_in_place: float = 0.5  # rad: above this heading error the robot only turns
    pass_radius: float = 0.15  # m: an intermediate waypoint is passed this close to its centre

    def __post_init__(self) -> None:
        for name in ("max_linear", "max_angular", "linear_gain", "angular_gain", "linear_decel", "angular_decel",
                     "turn_in_place", "pass_radius"):
            if not getattr(self, name) > 0:
                raise ValueError(f"{name} must be positive, got {getattr(self, name)}")


@dataclass(frozen=True)
class Command:
    linear: float  # m/s, forward
    angular: float  # rad/s, counter-clockwise
    waypoint: int  # index of the waypoint being driven to (len(waypoints): all reached)
    arrived: bool  # within the tolerance of the last waypoint: the command is a stop


def wrap_angle(angle: float) -> float:
    """``angle`` in [-pi, pi)."""
    return (angle + math.pi) % (2 * math.pi) - math.pi


def go_to(x: float, y: float, yaw: float, waypoints: list[tuple[float, float]], waypoint: int,
          tolerance: float, settings: ControllerSettings = ControllerSettings()) -> Command:
    """The command for a robot at ``(x, y, yaw)`` (map frame) driving to ``waypoints[waypoint]``
    and on to the last, where it stops within ``tolerance`` metres."""
    if not waypoints:
        raise ValueError("no waypoint to drive to")
    last = len(waypoints) - 1
    while waypoint < last and math.dist((x, y), waypoints[waypoint]) <= settings.pass_radius:
        waypoint += 1
    tx, ty = waypoints[min(waypoint, last)]
    distance = math.hypot(tx - x, ty - y)
    if waypoint >= last and distance <= tolerance:
        return Command(0.0, 0.0, last + 1, True)
    error = wrap_angle(math.atan2(ty - y, tx - x) - yaw)
    turn = min(settings.max_angular, settings.angular_gain * abs(error),
               math.sqrt(2 * settings.angular_decel * abs(error)))
    angular = math.copysign(turn, error)
    if abs(error) > settings.turn_in_place:
        return Command(0.0, angular, waypoint, False)
    linear = min(settings.max_linear, settings.linear_gain * distance,
                 math.sqrt(2 * settings.linear_decel * distance)) * math.cos(error)
    return Command(linear, angular, waypoint, False)
