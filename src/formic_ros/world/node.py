"""The world node: owns the simulation core and steps it with its agents over ROS.

Lockstep (default) or free-running (``rate_hz``), step 0 waiting for every agent, as docs/ros.md
("Lockstep, deadlines and free-running") describes. Observations go out batched on
``observations`` and per agent on ``agent_K/observation``, each only while it has a subscriber;
actions come in on ``actions`` and ``agent_K/action`` (the latter taken by the lockstep loop
itself: :mod:`formic_ros.intake`), validated and checked against their agent's owner
(:mod:`formic_ros.world.ownership`). The lockstep bookkeeping (inbox, deadlines,
re-sends, misses) is :mod:`formic_ros.world.lockstep`, what goes out :mod:`formic_ros.world.outbox`;
training mode :mod:`formic_ros.world.training`, the process around it :mod:`formic_ros.world.serve`.
"""

from __future__ import annotations

import dataclasses
import functools
import json
import sys
import threading
import time
from typing import Callable

import numpy as np
from formic_interfaces.msg import ActionBatch, AgentAction
from rclpy.duration import Duration
from rclpy.node import Node
from std_msgs.msg import String

from formic_runtime.episode import EpisodeStats
import formic_topics as topics
from formic_world import Scenario, World
from formic_world.metric_frame import MetricFrame

from .. import convert, qos
from ..graph import RecorderReports, recorders_present, settle_discovery, wait_for_recorders
from ..intake import Intake, lean_node, not_dispatched
from ..parameters import declare_settings, settings_of
from ..timeline import Timeline
from ..wire import encoding_code
from .lockstep import Lockstep, RateLimitedLog
from .options import WorldNodeOptions
from .outbox import WorldOutbox
from .ownership import Ownership
from .robot_steps import robot_link

INTAKE_CHUNK = 32  # per-agent actions: the world wakes when this many more are there, and takes them
# (taking costs ~7 µs a message in rclpy: taken all after the last, 128 held the step 1.1-1.2 ms after
# the host's last publish; 32 at a time, 0.96-1.06 ms; each of them, as the executor did, 1.45-1.58)
CLAIMS_WAIT_S = 2.0  # before step 0, at most this long for the claims of the claimants in the graph
ACK_TIMEOUT_S = 3.5  # at the end, how long subscribers get to acknowledge the last messages
# (acks follow Fast DDS's ~3 s heartbeats: waited for only with a recorder, planner or viewer)


class WorldNode(Node):
    """Node ``world`` in the ForMIC namespace; :meth:`run` plays one episode, :meth:`load`
    sets up the next (a new scenario for the same team size). ``why_absent(node)``: why no
    agent answered step 0 (default: what the ownership knows of the drivers)."""

    def __init__(self, scenario: Scenario, options: WorldNodeOptions = WorldNodeOptions(),
                 why_absent: Callable[[WorldNode], str | None] | None = None):
        super().__init__("world", namespace=options.namespace)
        self.options = options
        declare_settings(self, settings_of(options))
        n = self.n_agents = scenario.config.n_agents
        self.log = RateLimitedLog(self.get_logger())
        self.core_lock = threading.Lock()  # held while the core changes: other threads then read a whole step
        encoding_code(options.observation_encoding)  # an unknown encoding fails here, not at step 0
        self.outbox = WorldOutbox(self, n, options, lambda: self.metric_frame)
        self.timeline = Timeline("world")  # FORMIC_TIMELINE: where each step's time goes
        sub = functools.partial(convert.checked_subscription, self, on_malformed=self._on_malformed)
        self.actions_sub = sub(ActionBatch, topics.ACTIONS, qos.STREAM, self._on_action_batch)
        # the per-agent actions are taken by the lockstep loop itself, in agent order (formic_ros.intake)
        self.intake_node = lean_node(f"{self.get_name()}_actions", options.namespace)
        action_readers = [self.intake_node.create_subscription(
            AgentAction, topics.agent_topic(a, topics.AGENT_ACTION), not_dispatched, qos.STREAM, raw=True)
            for a in range(n)]
        self.action_intake = Intake(action_readers, self.context)
        self.action_topics = [reader.topic_name for reader in action_readers]
        self.recorder_reports = RecorderReports(self)
        self.why_absent = why_absent or (lambda node: node.ownership.why_nobody_answered())
        self.ownership = Ownership(self, self._on_owner_batch, sub,
                                   agent_readers={r.topic_name: r for r in action_readers},
                                   external=options.external, drivers=options.drivers,
                                   recorder_reports=self.recorder_reports)
        self._settled = False  # discovery has settled once (before the first episode)
        self.view = None  # the live view, fed after each step (formic_view; no ROS involved)
        if options.view_port is not None:
            from formic_view import LiveView, announcement

            self.view = LiveView(port=options.view_port, dt=options.dt)
            self.get_logger().info(announcement(self.view.url))
        self.robots = None  # robot agents (docs/robots.md): linked once the scenario is loaded
        self.load(scenario)
        if options.robots:
            self.robots = robot_link(self, scenario)

    def destroy_node(self) -> None:
        self.timeline.save()
        self.intake_node.destroy_node()
        super().destroy_node()

    @property
    def metric_frame(self) -> MetricFrame:
        """Where the current scenario's grid lies in the ``map`` frame (entity poses, robots, viewers)."""
        cfg, opts = self.scenario.config, self.options
        return MetricFrame(cfg.height, cfg.width, opts.cell_size, opts.origin_x, opts.origin_y)

    def load(self, scenario: Scenario) -> None:
        """The scenario of the next episode, published (latched) at once."""
        n = scenario.config.n_agents
        if n != self.n_agents:
            raise ValueError(f"a world node serves one team size ({self.n_agents} agents), not {n}")
        self.scenario = scenario
        with self.core_lock:
            self.world = World(scenario)
        opts = self.options
        self.lockstep = Lockstep(n, self.log, self.get_logger(), opts.deadline_s, opts.startup_timeout_s, opts.rate_hz,
                                 opts.allow_empty, owners=self.ownership, why_absent=lambda: self.why_absent(self),
                                 take_actions=self._take_agent_actions)
        self.inbox = self.lockstep.inbox
        self.ownership.count_into(self.inbox.rejected)
        self.outbox.scenario_pub.publish(convert.encode_scenario(scenario, opts.policy_label))

    # ------------------------------------------------------------------ actions in
    def _on_action_batch(self, msg: ActionBatch) -> None:
        step, ids, actions = convert.decode_actions(msg)
        self.inbox.offer(step, ids, actions, f"{topics.ACTIONS} ({len(ids)} agents)", self.actions_sub.topic_name)

    def _on_owner_batch(self, msg: ActionBatch, topic: str) -> None:
        """An owner's own batch topic (:mod:`formic_ros.world.ownership` subscribes it)."""
        self.inbox.offer(*convert.decode_actions(msg), topic, topic)

    def _on_malformed(self, topic: str, size: int) -> None:
        self.inbox.reject("malformed", 1, f"{topic}: {size} bytes that do not decode")

    def _on_agent_action(self, agent: int, data: bytes) -> None:
        """One agent's serialized action (decoded here: the common case, one per agent and step)."""
        if (fields := convert.decode_agent_action(data)) is None:
            self._on_malformed(self.action_topics[agent], len(data))
            return
        step, agent_id, action = fields
        if agent_id != agent:
            source = topics.agent_topic(agent, topics.AGENT_ACTION)
            self.inbox.reject("agent id mismatch", 1, f"{source}: message for agent {agent_id}")
            return
        self.inbox.offer_one(step, agent, action, self.action_topics[agent])

    def _take_agent_actions(self, timeout_s: float) -> bool:
        """Take the per-agent actions waiting, in agent order; if some are still missing, sleep
        until ``INTAKE_CHUNK`` more are there (or ``timeout_s``) and take again. False when no
        agent still missing has a per-agent publisher (its actions come batched, or not at all)."""
        inbox, intake = self.inbox, self.action_intake
        writers = intake.count_writers(time.monotonic(), fresh=inbox.step == 0)
        missing = np.flatnonzero(writers & ~inbox.received)
        if not len(missing):
            return False
        order = np.flatnonzero(writers).tolist()
        self._offer_agent_actions(intake.sweep(order))
        if (missing := missing[~inbox.received[missing]]).size:
            intake.wait(int(missing[min(len(missing), INTAKE_CHUNK) - 1]), timeout_s)  # hosts publish in agent order
            self._offer_agent_actions(intake.sweep(order))
        return True

    def _offer_agent_actions(self, taken: list[tuple[int, bytes]]) -> None:
        """Per-agent actions taken in one sweep ((agent, serialized)): decoded and offered as one
        array; any the common case does not cover goes through :meth:`_on_agent_action`."""
        if not taken:
            return
        agents = np.fromiter((agent for agent, _ in taken), dtype=np.int64, count=len(taken))
        records = convert.decode_agent_actions([data for _, data in taken])
        left = np.ones(len(taken), dtype=bool)
        if records is not None:
            own = records["agent_id"] == agents
            left[own] = self.inbox.offer_many(agents[own], records["step"][own].astype(np.int64),
                                              records["action"][own].astype(np.int64), self.action_topics)
        for i in np.flatnonzero(left).tolist():
            self._on_agent_action(*taken[i])

    # ---------------------------------------------------------------------- waiting
    def _wait_for_subscribers(self, executor) -> None:
        """Before step 0: ``require_subscribers`` are heard, and the recorders matched everything."""
        if not self._settled:  # recorders already running are discovered before they are counted
            settle_discovery(self, executor)
            self._settled = True
        # every claim of a node already in the graph is heard (and a stray one refused) before step 0
        deadline = time.monotonic() + CLAIMS_WAIT_S
        while self.ownership.unheard_claimants() and time.monotonic() < deadline:
            executor.spin_once(timeout_sec=0.05)
        if unheard := self.ownership.unheard_claimants():
            self.get_logger().warning(f"the claims of {', '.join(sorted(unheard))} have not arrived after "
                                      f"{CLAIMS_WAIT_S:g} s; starting anyway (a late claim is judged when it arrives)")
        self.ownership.expect_recorders(max(self.options.recorders, recorders_present(self)))  # drivers wait too
        deadline = time.monotonic() + self.options.startup_timeout_s
        required = self.outbox.by_topic
        while missing := [n for n in self.options.require_subscribers if required[n].get_subscription_count() == 0]:
            if time.monotonic() > deadline:
                self.get_logger().warning(
                    f"no subscriber on {missing} after {self.options.startup_timeout_s:g} s; starting anyway")
                return
            executor.spin_once(timeout_sec=0.05)
        expected = max(self.options.recorders, recorders_present(self))  # told about, or present at start
        self.ownership.expect_recorders(expected)
        publishers = [*self.outbox.everything, *(self.robots.publishers if self.robots is not None else ())]
        if expected:
            self.get_logger().info(f"waiting for {expected} recorder(s) to match every topic")
            if not wait_for_recorders(self, executor, publishers, expected, self.recorder_reports,
                                      self.options.startup_timeout_s):
                self.get_logger().warning("the recorder has not matched every topic; starting anyway")
        self.outbox.relisten()  # the recorder is one of the per-agent listeners

    # -------------------------------------------------------------------- episode
    def run(self, executor, last: bool = True) -> dict:
        """Play the episode; returns the summary (also published, latched, on ``summary``).
        ``last``: the process leaves afterwards, so the final messages get time to go out."""
        self.begin_episode(executor)
        while not self.world.done:
            self.step(executor)
        return self.end_episode(executor, last)

    def begin_episode(self, executor) -> None:
        """Before step 0: the subscribers asked for are heard, the initial state is out, and
        the episode's counters and clocks start."""
        from tqdm import tqdm

        opts, world, cfg = self.options, self.world, self.scenario.config
        self._wait_for_subscribers(executor)
        if self.view is not None and self.options.view_wait and not self.view.wait_for_viewer(0):
            self.get_logger().info(f"waiting for a viewer to subscribe at {self.view.url}")
            while not self.view.wait_for_viewer(0):  # spinning: the agents' discovery goes on meanwhile
                executor.spin_once(timeout_sec=0.1)
        with self.core_lock:
            self.result = world.last_result if world.t == 0 else world.reset(self.scenario)  # a new world is reset
        if self.robots is not None:  # every robot at its start cell
            self.robots.place(executor, world, opts.startup_timeout_s)
        self.book = EpisodeStats(cfg.n_agents, cfg.episode_steps)
        self.outbox.state(world, self.lockstep.missed)
        if self.view is not None:  # the start, as formic sim and formic replay show it
            self.view.publish(world)
        self.started = self.tick = time.monotonic()
        self.clock = {"stepping_from": self.started, "cpu_from": time.process_time()}
        deadline = f"lockstep, deadline {opts.deadline_s * 1e3:.0f} ms"
        mode = f"free-running at {opts.rate_hz} Hz" if opts.rate_hz else deadline
        self.get_logger().info(f"episode: {cfg.height}x{cfg.width}, {cfg.n_agents} agents, {cfg.episode_steps} "
                               f"steps, seed {self.scenario.seed}, {mode}")
        self._finish = None  # the last step's bookkeeping, done while the agents choose the next actions
        self._paused_at: float | None = None  # since when a client has held the world between steps
        self._bar = tqdm(total=cfg.episode_steps, disable=not opts.progress, file=sys.stderr, unit="step",
                         leave=False)

    def step(self, executor) -> None:
        """Step ``world.t``, whoever asks (the episode loop or a simulation_interfaces client):
        observations out, the agents' actions in (waiting as the mode says), the core steps.
        Its bookkeeping runs after the next step's observations went out, or at :meth:`settle`."""
        world = self.world
        t = world.t
        self._count_pause()
        self.inbox.open(t)
        self.timeline.mark("observe", t)
        self.outbox.observations(self.world, self.result)
        self.timeline.mark("sent", t)
        self.settle()
        t0 = time.monotonic()
        resend = functools.partial(self.outbox.observations, world, self.result)
        self.tick = self.lockstep.await_actions(executor, resend, self.started, self.tick)
        self.timeline.mark("heard", t)
        self.lockstep.count_misses(t)
        actions = self.inbox.close()
        t1 = time.monotonic()
        loads_before, queued_before = world.loads.copy(), world.queued.copy()
        with self.core_lock:  # (with robots: held while they drive, so readers see committed steps only)
            if self.robots is None:
                self.result = world.step(actions)
            else:  # committed once the robots are in their cells; failed moves become NO_ACTION
                report = self.robots.step(executor, world, actions)
                self.result, actions = report.result, report.applied
        self.timeline.mark("stepped", t)
        self._finish = functools.partial(self._finish_step, self.book, t, actions, loads_before, queued_before,
                                         t1 - t0, time.monotonic() - t1, final=world.done)
        if t == 0:  # speed is measured from here: start-up and discovery excluded
            self.clock = {"stepping_from": time.monotonic(), "cpu_from": time.process_time()}
        self._bar.update()

    def settle(self) -> None:
        """Do the last step's pending bookkeeping now (the world stops here for a while)."""
        if self._finish is not None:
            finish, self._finish = self._finish, None
            finish()

    def _count_pause(self) -> None:
        """The time a client held the world since :meth:`pause` is not stepping (steps_per_s)."""
        if self._paused_at is not None:
            self.clock["paused_s"] = self.clock.get("paused_s", 0.0) + time.monotonic() - self._paused_at
            self._paused_at = None

    def restart_clock(self) -> None:
        """The free-running clock counts from now (stepping resumes after a pause)."""
        self.tick = time.monotonic()

    def pause(self) -> None:
        """Stop between steps: the last step's bookkeeping now, and the next step's actions
        taken as they come (the planner answers ``applied_actions`` before a client asks for
        the step; hosts answer only observations, which the step sends)."""
        self.settle()
        self._paused_at = time.monotonic()
        if not self.world.done:
            self.inbox.open(self.world.t)

    def end_episode(self, executor, last: bool = True) -> dict:
        """After the last step: done observations (hosts stop answering), the summary."""
        world = self.world
        self.outbox.observations(self.world, self.result)  # done=True: hosts stop answering
        self.settle()
        self._bar.close()
        self._count_pause()
        self.clock.update(ended=time.monotonic(), cpu_to=time.process_time(), started=self.started)
        if last:
            self.outbox.linger(executor)
        summary = self.lockstep.summary(self.book, self.scenario, self.options.policy_label or "unknown", self.clock)
        if self.robots is not None:
            summary.update(self.robots.summary())
        self.outbox.summary_pub.publish(String(data=json.dumps(summary, default=float)))
        for publisher in (self.outbox.applied_pub, self.outbox.state_pub, self.outbox.summary_pub) if last else ():
            if publisher.get_subscription_count():
                publisher.wait_for_all_acked(Duration(seconds=ACK_TIMEOUT_S))
        self.get_logger().info(
            f"episode over: food {world.score:.1f}, {summary['missed_actions']} missed actions, "
            f"{sum(self.inbox.rejected.values())} rejected, {summary['steps_per_s']:.0f} steps/s"
        )
        return summary

    def abandon_episode(self) -> None:
        """End the episode before its last step (a reset): observations marked done tell the
        hosts to start afresh at the next step 0. No summary: the episode was not played out."""
        self.settle()
        self.outbox.observations(self.world, dataclasses.replace(self.result, done=True))
        self._bar.close()
        self.get_logger().info(f"episode abandoned at step {self.world.t} of {self.scenario.config.episode_steps}")

    def _finish_step(self, book: EpisodeStats, t: int, actions: np.ndarray, loads_before: np.ndarray,
                     queued_before: np.ndarray, wait_s: float, step_s: float, final: bool) -> None:
        """Step ``t``'s bookkeeping and messages (applied actions, state, viewers). The world
        has not moved since step ``t``, so this runs after the next observations went out,
        while the agents think: off the lockstep's critical path."""
        book.record(t, self.world, loads_before, queued_before, wait_s, step_s)
        self.outbox.applied(t, actions)
        self.outbox.state(self.world, self.lockstep.missed, final=final)
        if self.view is not None:
            self.view.publish(self.world, final=final)
