"""The robot bridge: one node per robot agent (``robot_bridge_K``) between the world and a robot
that speaks ``geometry_msgs/Twist`` and ``nav_msgs/Odometry`` (docs/robots.md).

Goals in (``agent_K/robot_goal``: cells and their centres in the map frame), velocity commands
out (``cmd_vel``) from the go-to-cell controller (:mod:`formic_robots.controller`), the robot's
pose in (``nav_msgs/Odometry``, or ``geometry_msgs/PoseStamped`` with ``--pose``), statuses out
(``agent_K/robot_status``: DRIVING a few times a second, then ARRIVED or FAILED). The bridge knows
nothing of what is at the other end of ``cmd_vel`` and the pose topic: a real robot, or
``formic robots-sim``.

The decisions for the robot come from an in-process agent host (:class:`AgentHost`, the node
``agent_K``: the same policies as every simulated agent), or, with ``policy="none"``, from the
user's own node ``agent_K`` (the world leaves K ``--external``; the bridge never publishes
actions, so it never competes with the agent's owner).
"""

from __future__ import annotations

import math
import os
import time
from contextlib import suppress

from formic_interfaces.msg import RobotGoal, RobotStatus
from geometry_msgs.msg import PoseStamped, Twist, Vector3
from nav_msgs.msg import Odometry
from rclpy.node import Node
from rclpy.qos import HistoryPolicy, QoSProfile, ReliabilityPolicy

import formic_topics as topics
from formic_robots.controller import go_to, wrap_angle
from formic_world.metric_frame import MAP_FRAME, MetricFrame

from .. import qos
from .settings import BridgeSettings

CONTROL_HZ = 20.0
DRIVING_EVERY_S = 0.2  # a DRIVING status (the robot's pose, for the live view) this often
POSE_STALE_S = 1.0  # a pose older than this is no pose: the robot is stopped
PROGRESS_M = 0.02  # getting this much closer to the goal (or turning 0.1 rad towards it) is progress
# Sensor-style reader: matches reliable and best-effort publishers (robots publish odometry either way).
SENSOR = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=5, reliability=ReliabilityPolicy.BEST_EFFORT)
COMMAND = qos.reliable(10)  # a reliable writer: also matches a best-effort reader

Pose = tuple[float, float, float]


def yaw_of(q) -> float:
    """The heading of a quaternion (rotation about z)."""
    return math.atan2(2.0 * (q.w * q.z + q.x * q.y), 1.0 - 2.0 * (q.y * q.y + q.z * q.z))


def parse_origin(text: str) -> Pose | None:
    """``"X,Y,YAW"`` -> the pose frame's origin in map; None for ``map`` and ``start``."""
    if text in ("map", "start"):
        return None
    try:
        x, y, yaw = (float(v) for v in text.split(","))
        if not all(map(math.isfinite, (x, y, yaw))):
            raise ValueError
    except ValueError:
        raise ValueError(f"odometry origin {text!r}: use map, start or X,Y,YAW (finite metres, radians)") from None
    return x, y, yaw


class RobotBridge:
    """The node ``robot_bridge_K`` for robot agent ``agent``; add :attr:`node` to an executor."""

    def __init__(self, agent: int, settings: BridgeSettings = BridgeSettings(),
                 namespace: str = topics.DEFAULT_NAMESPACE):
        self.agent, self.settings = agent, settings
        self.origin = parse_origin(settings.odom_origin)
        self.node = Node(f"robot_bridge_{agent}", namespace=namespace)
        self.log = self.node.get_logger()
        node = self.node
        node.create_subscription(RobotGoal, topics.agent_topic(agent, topics.ROBOT_GOAL), self._on_goal, qos.STREAM)
        self.status_pub = node.create_publisher(RobotStatus, topics.agent_topic(agent, topics.ROBOT_STATUS),
                                                qos.STREAM_WRITER)
        self.cmd_pub = node.create_publisher(Twist, settings.cmd_vel.format(agent=agent), COMMAND)
        if settings.pose:
            node.create_subscription(PoseStamped, settings.pose.format(agent=agent),
                                     lambda m: self._on_pose(m.header.frame_id, m.pose), SENSOR)
        else:
            node.create_subscription(Odometry, settings.odom.format(agent=agent),
                                     lambda m: self._on_pose(m.header.frame_id, m.pose.pose), SENSOR)
        node.create_timer(1.0 / CONTROL_HZ, self._control)
        self.pose: Pose | None = None  # in map
        self.pose_at = -math.inf
        self.goal: RobotGoal | None = None
        self.frame: MetricFrame | None = None
        self.outcome: RobotStatus | None = None  # the open goal's answer, once given (sent again on a copy)
        self._told_frame = False
        self._reset_progress()

    # ------------------------------------------------------------------------ inputs
    def _on_pose(self, frame_id: str, pose) -> None:
        x, y, yaw = pose.position.x, pose.position.y, yaw_of(pose.orientation)
        if self.origin is not None:
            ox, oy, oyaw = self.origin
            x, y = ox + math.cos(oyaw) * x - math.sin(oyaw) * y, oy + math.sin(oyaw) * x + math.cos(oyaw) * y
            yaw = wrap_angle(yaw + oyaw)
        elif self.settings.odom_origin == "map" and frame_id not in (MAP_FRAME, "") and not self._told_frame:
            self._told_frame = True
            self.log.warning(f"poses arrive in frame {frame_id!r}: taken as {MAP_FRAME!r} (--odom-origin says "
                             "where that frame lies in the map)")
        elif self.settings.odom_origin == "start" and self.origin is None:
            return  # the start cell is not known before the placement goal
        self.pose, self.pose_at = (x, y, yaw), time.monotonic()

    def _on_goal(self, goal: RobotGoal) -> None:
        if goal.agent_id != self.agent:
            return
        key = (goal.step, goal.attempt)
        if self.goal is not None and key <= (self.goal.step, self.goal.attempt):
            if key == (self.goal.step, self.goal.attempt) and self.outcome is not None:
                self.status_pub.publish(self.outcome)  # the world missed the answer
            return
        if goal.step == RobotGoal.PLACEMENT and self.settings.odom_origin == "start" and self.origin is None:
            self.origin = (goal.xs[-1], goal.ys[-1], 0.0)  # the robot was switched on at its start cell, facing east
            self.log.info(f"odometry origin: the start cell's centre ({goal.xs[-1]:.3f}, {goal.ys[-1]:.3f}), "
                          "facing east")
        self.goal, self.outcome = goal, None
        self.frame = MetricFrame(goal.height, goal.width, goal.cell_size, goal.origin_x, goal.origin_y)
        self.received_at = time.monotonic()
        self._reset_progress()

    # ------------------------------------------------------------------------ control
    def _reset_progress(self) -> None:
        self.waypoint = 0
        self.best = math.inf  # the least distance left (metres, plus radians of heading) so far
        self.progress_at = time.monotonic()
        self.next_driving = 0.0

    def _status(self, status: int, distance: float) -> RobotStatus:
        goal, (x, y, yaw) = self.goal, self.pose or (math.nan, math.nan, math.nan)
        cell = self.frame.cell_at(x, y) if self.pose is not None else None
        row, col = cell if cell is not None else (-1, -1)
        return RobotStatus(agent_id=self.agent, step=goal.step, attempt=goal.attempt, status=status, row=row, col=col,
                           x=x, y=y, yaw=yaw, distance=distance)

    def _finish(self, status: int, distance: float) -> None:
        self.cmd_pub.publish(Twist())
        self.outcome = self._status(status, distance)
        self.status_pub.publish(self.outcome)

    def _control(self) -> None:
        goal = self.goal
        if goal is None or self.outcome is not None:
            return
        now = time.monotonic()
        points = list(zip(goal.xs, goal.ys))
        fresh = self.pose is not None and now - self.pose_at <= POSE_STALE_S
        distance = math.dist(self.pose[:2], points[-1]) if self.pose is not None else math.inf
        if now - self.received_at > goal.timeout_s:
            self.log.warning(f"step {goal.step}: out of time {distance:.2f} m from the goal", throttle_duration_sec=2.0)
            self._finish(RobotStatus.FAILED, distance)
            return
        if not fresh:
            self.cmd_pub.publish(Twist())
            self.log.warning("no recent pose: the robot is stopped", throttle_duration_sec=5.0)
            return
        x, y, yaw = self.pose
        command = go_to(x, y, yaw, points, self.waypoint, goal.tolerance / 2, self.settings.controller)
        if command.arrived:
            self._finish(RobotStatus.ARRIVED, distance)
            return
        self.waypoint = command.waypoint
        target = points[min(self.waypoint, len(points) - 1)]
        left = math.dist((x, y), target) + abs(wrap_angle(math.atan2(target[1] - y, target[0] - x) - yaw)) * 0.2
        left += sum(math.dist(a, b) for a, b in zip(points[self.waypoint:], points[self.waypoint + 1:]))
        if left < self.best - PROGRESS_M:
            self.best, self.progress_at = left, now
        elif now - self.progress_at > self.settings.stall_s:
            self.log.warning(f"step {goal.step}: no progress for {self.settings.stall_s:g} s: blocked")
            self._finish(RobotStatus.FAILED, distance)
            return
        self.cmd_pub.publish(Twist(linear=Vector3(x=command.linear), angular=Vector3(z=command.angular)))
        if now >= self.next_driving:
            self.status_pub.publish(self._status(RobotStatus.DRIVING, distance))
            self.next_driving = now + DRIVING_EVERY_S


def serve_robots(agent_ids: list[int], policy: str = "formic", settings: BridgeSettings = BridgeSettings(),
                 namespace: str = topics.DEFAULT_NAMESPACE, name: str | None = None, model: str | None = None,
                 greedy: bool = False, once: bool = False, domain_id: int | None = None,
                 external: list[int] = ()) -> None:
    """A bridge node per robot agent, and (unless ``policy`` is ``none``) one agent host deciding
    for those not in ``external`` (their own nodes decide for those); until interrupted (``once``:
    until the episode ends, or, with no host, until the world that sent goals leaves)."""
    from ..drivers.agent_host import AgentHost
    from ..drivers.world_watch import WorldWatch
    from ..env import ros_session

    decided = [a for a in agent_ids if a not in external] if policy != "none" else []
    with ros_session(domain_id) as executor:
        host = None
        if decided:
            host = AgentHost(decided, policy, model=model, greedy=greedy, namespace=namespace,
                             name=name or f"robot_bridge_host_{os.getpid()}", intake=False)
            for node in host.nodes:
                executor.add_node(node)
        bridges = [RobotBridge(a, settings, namespace) for a in agent_ids]
        for bridge in bridges:
            executor.add_node(bridge.node)
        watch = WorldWatch(host) if host is not None else None

        def over() -> bool:
            if host is None:  # only driving: over when the world that sent the goals has left
                return any(b.goal is not None for b in bridges) and not bridges[0].node.count_publishers(
                    topics.SCENARIO)
            return host.finished or (not host.finished and watch.ended(host.answered_step + 1, host.horizon))

        with suppress(KeyboardInterrupt):
            while not (once and over()):
                executor.spin_once(timeout_sec=0.1)
        for bridge in bridges:  # leave the robots standing
            bridge.cmd_pub.publish(Twist())
