"""A kinematic differential-drive (unicycle) robot: the model ``formic robots-sim`` integrates.

The commanded velocity (``cmd_vel``: forward speed and turn rate) is clipped to the speed limits,
approached at most at the acceleration limits, and executed with seeded multiplicative noise
(wheels slip: a robot never quite drives what it is told, so a controller must close the loop
on odometry). A robot may also stall (its wheels stop for a while, as when it is blocked),
which is how the simulator makes moves fail. A command older than ``command_timeout_s`` counts
as a stop, like a real base's watchdog.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from .controller import wrap_angle


@dataclass(frozen=True)
class UnicycleLimits:
    max_linear: float = 0.5  # m/s
    max_angular: float = 2.5  # rad/s
    linear_accel: float = 1.0  # m/s^2
    angular_accel: float = 5.0  # rad/s^2
    noise: float = 0.05  # standard deviation of the executed/commanded velocity ratio
    command_timeout_s: float = 0.5  # a command older than this is a stop
    stall_rate: float = 0.0  # stalls per second of driving (Poisson)
    stall_s: float = 3.0  # how long a stall lasts

    def __post_init__(self) -> None:
        for name in ("max_linear", "max_angular", "linear_accel", "angular_accel", "command_timeout_s", "stall_s"):
            if not getattr(self, name) > 0:
                raise ValueError(f"{name} must be positive, got {getattr(self, name)}")
        if self.noise < 0 or self.stall_rate < 0:
            raise ValueError("noise and stall_rate must not be negative")


@dataclass
class Unicycle:
    """One robot's true state in the map frame; :meth:`advance` integrates it."""

    x: float
    y: float
    yaw: float
    linear: float = 0.0  # executed velocities (what odometry reports)
    angular: float = 0.0
    stalled_until: float = -math.inf  # sim time until which the wheels are stopped

    def advance(self, now: float, dt: float, command: tuple[float, float], commanded_at: float,
                limits: UnicycleLimits, rng: np.random.Generator) -> None:
        """Integrate ``dt`` seconds ending at sim time ``now`` under ``command`` (sent at ``commanded_at``)."""
        want_v, want_w = command if now - commanded_at <= limits.command_timeout_s else (0.0, 0.0)
        if limits.stall_rate > 0 and (want_v or want_w) and rng.random() < limits.stall_rate * dt:
            self.stalled_until = now + limits.stall_s
        if now < self.stalled_until:
            want_v = want_w = 0.0
        want_v = max(-limits.max_linear, min(limits.max_linear, want_v))
        want_w = max(-limits.max_angular, min(limits.max_angular, want_w))
        self.linear += max(-limits.linear_accel * dt, min(limits.linear_accel * dt, want_v - self.linear))
        self.angular += max(-limits.angular_accel * dt, min(limits.angular_accel * dt, want_w - self.angular))
        slip_v, slip_w = (1.0 + limits.noise * rng.standard_normal(2)) if limits.noise else (1.0, 1.0)
        v, w = self.linear * slip_v, self.angular * slip_w
        heading = self.yaw + w * dt / 2  # midpoint rule: exact enough for small dt
        self.x += v * math.cos(heading) * dt
        self.y += v * math.sin(heading) * dt
        self.yaw = wrap_angle(self.yaw + w * dt)
