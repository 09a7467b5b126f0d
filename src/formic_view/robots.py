"""Robots in the live view: each robot agent as a robot (a disc with an arrow for its heading) at
its measured pose, over the grid, on the channel ``/formic/robots`` (``foxglove.SceneUpdate``).

The live view draws the grid one unit a cell (:mod:`formic_view.live`); a robot's pose in the
``map`` frame (metres, :class:`formic_world.metric_frame.MetricFrame`) is drawn at its place on
that grid, so a robot between two cells is seen between them, and one off its cell's centre is
seen off it. With the default frame (1 m cells, origin 0) both are the same numbers.
"""

from __future__ import annotations

import math
from collections.abc import Callable

from foxglove.channels import SceneUpdateChannel
from foxglove.messages import (ArrowPrimitive, Color, CylinderPrimitive, Pose, Quaternion, SceneEntity, SceneUpdate,
                                Timestamp, Vector3)

from formic_world.metric_frame import MetricFrame

from .live import FRAME, LiveView

ROBOTS_TOPIC = "/formic/robots"
ROBOT_COLOUR = Color(r=0.85, g=0.1, b=0.6, a=0.9)
ROBOT_DIAMETER = 0.7  # cells


def robot_scene(poses: dict[int, tuple[float, float, float]], frame: MetricFrame, stamp: Timestamp) -> SceneUpdate:
    """One entity per robot (id ``robot_K``): a disc at its pose and an arrow along its heading."""
    entities = []
    for agent, (x, y, yaw) in sorted(poses.items()):
        gx, gy = (x - frame.origin_x) / frame.cell_size, (y - frame.origin_y) / frame.cell_size
        heading = Quaternion(z=math.sin(yaw / 2), w=math.cos(yaw / 2))
        at = Pose(position=Vector3(x=gx, y=gy, z=0.1), orientation=heading)
        entities.append(SceneEntity(
            timestamp=stamp, frame_id=FRAME, id=f"robot_{agent}", frame_locked=True,
            cylinders=[CylinderPrimitive(pose=at, size=Vector3(x=ROBOT_DIAMETER, y=ROBOT_DIAMETER, z=0.2),
                                         bottom_scale=1.0, top_scale=1.0, color=ROBOT_COLOUR)],
            arrows=[ArrowPrimitive(pose=Pose(position=Vector3(x=gx, y=gy, z=0.25), orientation=heading),
                                   shaft_length=0.35, shaft_diameter=0.08, head_length=0.2, head_diameter=0.2,
                                   color=Color(r=1.0, g=1.0, b=1.0, a=1.0))]))
    return SceneUpdate(entities=entities)


class RobotLayer:
    """The robots' channel on a :class:`LiveView`; :meth:`publish` the robots' latest poses,
    stamped with ``sim_time()`` (seconds: the step they drive in, as the view's other channels)."""

    def __init__(self, view: LiveView, frame: MetricFrame, sim_time: Callable[[], float]):
        self.frame, self.sim_time = frame, sim_time
        self.channel = SceneUpdateChannel(ROBOTS_TOPIC, context=view.context)

    def publish(self, poses: dict[int, tuple[float, float, float]]) -> None:
        if self.channel.has_sinks():
            nanos = int(round(self.sim_time() * 1e9))
            stamp = Timestamp(nanos // 1_000_000_000, nanos % 1_000_000_000)
            self.channel.log(robot_scene(poses, self.frame, stamp), log_time=nanos)
