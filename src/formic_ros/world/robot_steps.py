"""The world node's side of its robot agents: goals out on ``agent_K/robot_goal``, statuses in on
``agent_K/robot_status`` (only from the robot's own bridge: :meth:`Ownership.status_allowed
<formic_ros.world.ownership.Ownership.status_allowed>`), and the robot-paced step (:func:`formic_robots.steps.robot_paced_step`)
driven over them (docs/robots.md).

Before step 0 every robot confirms it stands at its agent's start cell (a placement goal, sent
until answered). Each step, after the agents' actions are in, the step is applied tentatively
and the robots are sent their routes wave by wave; a wave ends when each of its robots answered
(ARRIVED within the tolerance, or FAILED) or its deadline passed (``cell_s`` a cell of route,
plus ``GRACE_S`` for the messages). Unanswered goals are sent again every ``RESEND_S``: a lost
goal costs that long, not a deadline.
"""

from __future__ import annotations

import time
from collections import Counter
from collections.abc import Callable

from formic_interfaces.msg import RobotGoal, RobotStatus
from rclpy.node import Node

import formic_topics as topics
from formic_robots.steps import Route, RobotStepReport, RobotStuck, robot_paced_step
from formic_world import World
from formic_world.metric_frame import MetricFrame

from .. import qos
from ..errors import RunError

RESEND_S = 0.5  # an unanswered goal is sent again this often
GRACE_S = 1.0  # the world waits this much longer than the goal's own timeout (the answer travels)
POSE_EVERY_S = 0.1  # robot poses go to the live view at most this often

Pose = tuple[float, float, float]  # x, y, yaw in the map frame


class RobotLink:
    """Goal publishers and status readers of ``robots`` on ``node``; :meth:`place` before step 0,
    :meth:`step` instead of ``World.step``. ``on_poses`` gets every robot's latest reported pose
    while they drive (the live view), at most every ``POSE_EVERY_S``."""

    def __init__(self, node: Node, robots: tuple[int, ...], frame: MetricFrame, tolerance: float, cell_s: float,
                 log, on_poses: Callable[[dict[int, Pose]], None] | None = None, owners=None):
        if not 0 < tolerance < frame.cell_size / 2:
            raise RunError(f"the robot tolerance ({tolerance} m) must be under half a cell ({frame.cell_size} m)")
        self.robots, self.frame, self.tolerance, self.cell_s = tuple(robots), frame, tolerance, cell_s
        self.log, self.on_poses = log, on_poses
        self.goal_pubs = {r: node.create_publisher(RobotGoal, topics.agent_topic(r, topics.ROBOT_GOAL),
                                                   qos.STREAM_WRITER) for r in self.robots}
        self.owners = owners  # the world's Ownership: statuses only from each robot's own bridge
        self.rejected: Counter = Counter()  # statuses not taken, by reason (the summary's rejected_statuses)
        self.status_readers = {r: node.create_subscription(RobotStatus, topics.agent_topic(r, topics.ROBOT_STATUS),
                                                           lambda msg, r=r: self._on_status(r, msg), qos.STREAM)
                               for r in self.robots}
        self.poses: dict[int, Pose] = {}
        self.awaited: dict[int, tuple[int, int, Route]] = {}  # robot -> (step, attempt, route) of its open goal
        self.answers: dict[int, bool] = {}  # robot -> arrived, for the open goals
        self.step_seconds: list[float] = []  # wall time of each committed step's driving
        self.failures = 0  # moves that failed (the robot did nothing instead)
        self.attempts = 0  # step applications, re-applications included

    @property
    def publishers(self) -> list:
        return list(self.goal_pubs.values())

    # ------------------------------------------------------------------ statuses in
    def _on_status(self, robot: int, msg: RobotStatus) -> None:
        if msg.agent_id != robot:
            self.rejected["agent id mismatch"] += 1
            return
        if self.owners is not None and not self.owners.status_allowed(robot, self.status_readers[robot],
                                                                       self.rejected):
            return
        self.poses[robot] = (msg.x, msg.y, msg.yaw)
        step, attempt, route = self.awaited.get(robot, (None, None, ()))
        if (msg.step, msg.attempt) != (step, attempt) or msg.status == RobotStatus.DRIVING or robot in self.answers:
            return
        goal = route[-1]
        arrived = msg.status == RobotStatus.ARRIVED
        if arrived and (self.frame.distance_to_cell(msg.x, msg.y, *goal) > self.tolerance
                        or (msg.row, msg.col) != goal):
            self.log("robot off its cell", f"robot {robot} reports arrival at ({msg.x:.3f}, {msg.y:.3f}), "
                     f"not within {self.tolerance} m of cell {goal}: counted as failed")
            arrived = False
        self.answers[robot] = arrived

    # ------------------------------------------------------------------ goals out
    def _goal(self, robot: int, step: int, attempt: int, route: Route, timeout_s: float) -> RobotGoal:
        centres = [self.frame.cell_centre(*cell) for cell in route]
        f = self.frame
        return RobotGoal(agent_id=robot, step=step, attempt=attempt, rows=[c[0] for c in route],
                         cols=[c[1] for c in route], xs=[c[0] for c in centres], ys=[c[1] for c in centres],
                         tolerance=self.tolerance, timeout_s=timeout_s, cell_size=f.cell_size,
                         origin_x=f.origin_x, origin_y=f.origin_y, height=f.height, width=f.width)

    def _drive(self, executor, step: int, attempt: int, routes: dict[int, Route], timeout_s: float | None = None,
               what: str = "") -> dict[int, bool]:
        """Send ``routes`` and wait for every answer (or the deadline); returns who arrived."""
        timeout = timeout_s or self.cell_s * max(len(route) for route in routes.values())
        goals = {r: self._goal(r, step, attempt, route, timeout) for r, route in routes.items()}
        self.awaited = {r: (step, attempt, route) for r, route in routes.items()}
        self.answers = {}
        deadline = time.monotonic() + timeout + GRACE_S
        next_send = next_pose = 0.0
        while len(self.answers) < len(goals):
            now = time.monotonic()
            if now >= deadline:
                late = sorted(set(goals) - set(self.answers))
                self.log("robot late", f"{what or f'step {step}'}: robots {late} did not answer within {timeout:g} s")
                break
            if now >= next_send:
                for r, goal in goals.items():
                    if r not in self.answers:
                        self.goal_pubs[r].publish(goal)
                next_send = now + RESEND_S
            if self.on_poses is not None and now >= next_pose and self.poses:
                self.on_poses(dict(self.poses))
                next_pose = now + POSE_EVERY_S
            executor.spin_once(timeout_sec=min(0.05, max(0.0, deadline - now)))
        self.awaited = {}
        return {r: self.answers.get(r, False) for r in goals}

    def place(self, executor, world: World, timeout_s: float) -> None:
        """Before step 0: every robot at its start cell (it is told to be there, and may drive the
        last bit); raises RunError naming those that are not within ``timeout_s``."""
        routes = {r: ((int(world.pos[r, 0]), int(world.pos[r, 1])),) for r in self.robots}
        arrived = self._drive(executor, RobotGoal.PLACEMENT, 0, routes, timeout_s=timeout_s, what="placement")
        missing = sorted(r for r, ok in arrived.items() if not ok)
        if missing:
            where = "; ".join(f"robot {r}: start cell {routes[r][0]} at {self.frame.cell_centre(*routes[r][0])}, "
                              f"last pose {self.poses.get(r, 'unknown')}" for r in missing)
            raise RunError(f"robots {missing} did not confirm their start cells within {timeout_s:g} s "
                               f"(is each robot's bridge running and placed?): {where}")

    def step(self, executor, world: World, actions) -> RobotStepReport:
        """``World.step(actions)``, committed once the robots are in their cells (failed moves:
        NO_ACTION in the report's ``applied``)."""
        started = time.monotonic()
        t = world.t
        try:
            report = robot_paced_step(world, actions, self.robots,
                                      lambda attempt, routes: self._drive(executor, t, attempt, routes))
        except RobotStuck as exc:
            raise RunError(str(exc)) from exc
        self.step_seconds.append(time.monotonic() - started)
        self.attempts += len(report.attempts)
        self.failures += len(report.failed)
        if report.failed:
            self.log("robot move failed", f"step {t}: robots {report.failed} did not reach their cells; "
                     f"they did nothing this step ({len(report.attempts)} attempts)")
        return report

    def summary(self) -> dict:
        seconds = self.step_seconds or [0.0]
        return {"robots": list(self.robots), "robot_failed_moves": self.failures,
                "robot_step_attempts": self.attempts, "robot_step_s_mean": sum(seconds) / len(seconds),
                "robot_step_s_max": max(seconds), "cell_size": self.frame.cell_size,
                "rejected_statuses": dict(self.rejected)}


def robot_link(node, scenario) -> RobotLink:
    """The world node's link to its robot agents, on the node's options (``robots``, the metric
    frame, ``robot_tolerance``, ``robot_cell_s``); the live view, if any, draws the robots."""
    opts, cfg = node.options, scenario.config
    outside = [r for r in opts.robots if not 0 <= r < cfg.n_agents]
    if outside:
        raise RunError(f"robots {outside} are not agents of this team of {cfg.n_agents}")
    frame = node.metric_frame
    on_poses = None
    if node.view is not None:
        from formic_view.robots import RobotLayer

        on_poses = RobotLayer(node.view, frame, lambda: node.world.t * opts.dt).publish
    return RobotLink(node, tuple(opts.robots), frame, opts.robot_tolerance, opts.robot_cell_s, node.log, on_poses,
                     owners=node.ownership)
