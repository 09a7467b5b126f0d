"""``formic robots-sim``: a kinematic simulator of several differential-drive robots, the stand-in
for hardware (docs/robots.md).

Robot K follows ``geometry_msgs/Twist`` on ``/robot_K/cmd_vel`` (:class:`formic_robots.unicycle.Unicycle`:
speed and acceleration limits, seeded slip noise, optional stalls) and publishes
``nav_msgs/Odometry`` on ``/robot_K/odom`` and its transform ``map -> robot_K/base_link`` on
``/tf`` at ``rate_hz``. Its odometry is its true pose in the ``map`` frame (a perfectly localised
robot, as in a camera-tracked arena). Each robot starts at the centre of its agent's start cell,
facing east, as soon as the world's latched scenario names it; it is a plain ROS node that knows
nothing of the bridge, and the bridge knows nothing of it.
"""

from __future__ import annotations

import math
import time
from contextlib import suppress

import numpy as np
from formic_interfaces.msg import ScenarioDescription
from geometry_msgs.msg import Quaternion, TransformStamped, Twist
from nav_msgs.msg import Odometry
from rclpy.node import Node
from tf2_msgs.msg import TFMessage

import formic_topics as topics
from formic_robots.unicycle import Unicycle
from formic_world.metric_frame import MAP_FRAME, MetricFrame

from .. import qos
from .settings import SimSettings
from ..drivers.world_watch import read_scenario
from .bridge import COMMAND

SENSOR_WRITER = qos.reliable(5)  # odometry: a reliable writer matches best-effort and reliable readers
MAX_TICK_S = 0.1  # a late timer integrates at most this long at once


def quaternion(yaw: float) -> Quaternion:
    return Quaternion(z=math.sin(yaw / 2), w=math.cos(yaw / 2))


class RobotsSim(Node):
    """Node ``robots_sim`` (outside the ForMIC namespace: it stands for the robots themselves)."""

    def __init__(self, agent_ids: list[int], settings: SimSettings = SimSettings(),
                 namespace: str = topics.DEFAULT_NAMESPACE):
        super().__init__("robots_sim")
        self.ids, self.settings = list(agent_ids), settings
        self.robots: dict[int, Unicycle] = {}
        self.rngs = {a: np.random.default_rng([settings.seed, a]) for a in self.ids}
        self.commands = {a: ((0.0, 0.0), -math.inf) for a in self.ids}
        self.odom_pubs = {a: self.create_publisher(Odometry, settings.odom.format(agent=a), SENSOR_WRITER)
                          for a in self.ids}
        for a in self.ids:
            self.create_subscription(Twist, settings.cmd_vel.format(agent=a),
                                     lambda m, a=a: self._on_cmd(a, m), COMMAND)
        self.tf_pub = self.create_publisher(TFMessage, "/tf", qos.reliable(100))
        scenario_topic = topics.full_name(namespace, topics.SCENARIO)
        self.create_subscription(ScenarioDescription, scenario_topic, self._on_scenario, qos.LATCHED)
        self.scenario_json = ""
        self.sim_time = 0.0  # seconds since start, wall clock: robots move in real time
        self.last_tick = time.monotonic()
        self.create_timer(1.0 / settings.rate_hz, self._tick)
        self.get_logger().info(f"robots {self.ids}: waiting for the world's scenario on {scenario_topic}")

    def _on_scenario(self, msg: ScenarioDescription) -> None:
        if msg.scenario_json == self.scenario_json or (scenario := read_scenario(msg, self.get_logger())) is None:
            return
        self.scenario_json = msg.scenario_json
        cfg, s = scenario.config, self.settings
        frame = MetricFrame(cfg.height, cfg.width, s.cell_size, *s.origin)
        for a in self.ids:
            if a >= cfg.n_agents:
                self.get_logger().error(f"robot {a} is not in this team of {cfg.n_agents}")
                continue
            start = scenario.agents[a]
            self.robots[a] = Unicycle(*frame.cell_centre(start.row, start.col), yaw=0.0)
        self.get_logger().info(f"robots placed at their agents' start cells (seed {scenario.seed})")

    def _on_cmd(self, agent: int, msg: Twist) -> None:
        self.commands[agent] = ((msg.linear.x, msg.angular.z), self.sim_time)

    def _tick(self) -> None:
        now = time.monotonic()
        dt, self.last_tick = min(MAX_TICK_S, now - self.last_tick), now
        self.sim_time += dt
        stamp = self.get_clock().now().to_msg()
        transforms = []
        for a, robot in self.robots.items():
            command, at = self.commands[a]
            robot.advance(self.sim_time, dt, command, at, self.settings.limits, self.rngs[a])
            odom = Odometry(child_frame_id=f"robot_{a}/base_link")
            odom.header.stamp, odom.header.frame_id = stamp, MAP_FRAME
            odom.pose.pose.position.x, odom.pose.pose.position.y = robot.x, robot.y
            odom.pose.pose.orientation = quaternion(robot.yaw)
            odom.twist.twist.linear.x, odom.twist.twist.angular.z = robot.linear, robot.angular
            self.odom_pubs[a].publish(odom)
            tf = TransformStamped(child_frame_id=odom.child_frame_id)
            tf.header = odom.header
            tf.transform.translation.x, tf.transform.translation.y = robot.x, robot.y
            tf.transform.rotation = odom.pose.pose.orientation
            transforms.append(tf)
        if transforms:
            self.tf_pub.publish(TFMessage(transforms=transforms))


def serve_robots_sim(agent_ids: list[int], settings: SimSettings = SimSettings(),
                     namespace: str = topics.DEFAULT_NAMESPACE, once: bool = False,
                     domain_id: int | None = None) -> None:
    """Simulate the robots until interrupted (``once``: until the world that placed them leaves)."""
    from ..env import ros_session

    with ros_session(domain_id) as executor:
        sim = RobotsSim(agent_ids, settings, namespace)
        executor.add_node(sim)
        scenario_topic = topics.full_name(namespace, topics.SCENARIO)
        with suppress(KeyboardInterrupt):
            while not (once and sim.robots and not sim.count_publishers(scenario_topic)):
                executor.spin_once(timeout_sec=0.1)
