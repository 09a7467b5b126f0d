"""The world node: owns the simulation core and steps it with its agents over ROS.

Lockstep (default) or free-running (``rate_hz``), step 0 waiting for every agent, as docs/ros.md
("Lockstep, deadlines and free-running") describes. Observations go out batched on
``observations`` and per agent on ``agent_K/observation``, each only while it has a subscriber;
actions come in on ``actions`` and ``agent_K/action``, validated and checked against their
agent's owner (:mod:`formic_ros.ownership`). The lockstep bookkeeping (inbox, deadlines,
re-sends, misses) is :mod:`formic_ros.lockstep`; training mode :mod:`formic_ros.training_world`.
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
from formic_interfaces.msg import (ActionBatch, AgentAction, AgentObservation, ObservationBatch,
                                   ScenarioDescription, WorldState)
from rclpy.duration import Duration
from rclpy.node import Node
from std_msgs.msg import Float64, String

from formic_agent.policy import AgentBatch
from formic_runtime.episode import EpisodeStats
import formic_topics as topics
from formic_world import Scenario, StepResult, World
from formic_world.metric_frame import MetricFrame

from .graph import RecorderReports, recorders_present, settle_discovery, wait_for_recorders
from . import convert, qos, viewer_msgs
from .lockstep import Lockstep, RateLimitedLog
from .parameters import declare_settings, settings_of
from .robot_steps import robot_link
from .ownership import Ownership, batch_of
from .wire import encoding_code, read
from .world_options import WorldNodeOptions

CLAIMS_WAIT_S = 2.0  # before step 0, at most this long for the claims of the claimants in the graph
LISTENER_REFRESH_S = 0.25  # how often the set of per-agent observation subscribers is re-read
LINGER_S = 0.5  # the node stays up at most this long after the episode's last messages
LINGER_POLL_S = 0.02  # how often it looks whether their readers have left
ACK_TIMEOUT_S = 3.5  # at the end, how long subscribers get to acknowledge the last messages
# (acks follow Fast DDS's ~3 s heartbeats: waited for only with a recorder, planner or viewer)


class WorldNode(Node):
    """Node ``world`` in the ForMIC namespace; :meth:`run` plays one episode, :meth:`load`
    sets up the next (a new scenario for the same team size)."""

    def __init__(self, scenario: Scenario, options: WorldNodeOptions = WorldNodeOptions()):
        super().__init__("world", namespace=options.namespace)
        self.options = options
        declare_settings(self, settings_of(options))
        n = self.n_agents = scenario.config.n_agents
        self.log = RateLimitedLog(self.get_logger())
        self.core_lock = threading.Lock()  # held while the core changes: other threads then read a whole step
        encoding_code(options.observation_encoding)  # an unknown encoding fails here, not at step 0

        pub = self.create_publisher
        self.scenario_pub = pub(ScenarioDescription, topics.SCENARIO, qos.LATCHED)
        self.summary_pub = pub(String, topics.SUMMARY, qos.LATCHED)
        self.observations_pub = pub(ObservationBatch, topics.OBSERVATIONS, qos.STREAM_WRITER)
        self.state_pub = pub(WorldState, topics.STATE, qos.LOG)
        self.applied_pub = pub(ActionBatch, topics.APPLIED_ACTIONS, qos.LOG)
        self.score_pub = pub(Float64, topics.SCORE, qos.LOG)
        self.clock_pub = pub(viewer_msgs.Clock, topics.CLOCK, qos.LOG)
        self.map_pub = pub(viewer_msgs.OccupancyGrid, topics.MAP, qos.VIEWER)
        self.markers_pub = pub(viewer_msgs.MarkerArray, topics.AGENT_MARKERS, qos.VIEWER)
        self.agent_obs_pubs = [pub(AgentObservation, topics.agent_topic(a, topics.AGENT_OBSERVATION), qos.STREAM_WRITER)
                               for a in range(n)]
        sub = functools.partial(convert.checked_subscription, self, on_malformed=self._on_malformed)
        self.actions_sub = sub(ActionBatch, topics.ACTIONS, qos.STREAM, self._on_action_batch)
        action_readers = [sub(AgentAction, topics.agent_topic(a, topics.AGENT_ACTION), qos.STREAM,
                              lambda m, a=a: self._on_agent_action(a, m)) for a in range(n)]
        self.action_topics = [reader.topic_name for reader in action_readers]
        self.recorder_reports = RecorderReports(self)
        self.ownership = Ownership(self, lambda msg, topic: self.inbox.offer(*batch_of(msg), topic, topic), sub,
                                   agent_readers={r.topic_name: r for r in action_readers},
                                   external=options.external, drivers=options.drivers,
                                   recorder_reports=self.recorder_reports)
        self._listening, self._listening_at = [], -np.inf
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
                                 opts.allow_empty)
        self.inbox = self.lockstep.inbox
        self.inbox.owners, self.ownership.rejected = self.ownership, self.inbox.rejected
        self.lockstep.why_absent = self.ownership.why_nobody_answered
        self.scenario_pub.publish(convert.encode_scenario(scenario, opts.policy_label))

    # ------------------------------------------------------------------ actions in
    def _on_action_batch(self, msg: ActionBatch) -> None:
        ids = read(msg.agent_ids, np.uint32)
        self.inbox.offer(msg.step, ids, read(msg.actions, np.uint8), f"{topics.ACTIONS} ({len(ids)} agents)",
                         self.actions_sub.topic_name)

    def _on_malformed(self, topic: str, size: int) -> None:
        self.inbox.reject("malformed", 1, f"{topic}: {size} bytes that do not decode")

    def _on_agent_action(self, agent: int, msg: AgentAction) -> None:
        if msg.agent_id != agent:
            source = topics.agent_topic(agent, topics.AGENT_ACTION)
            self.inbox.reject("agent id mismatch", 1, f"{source}: message for agent {msg.agent_id}")
            return
        self.inbox.offer_one(msg.step, agent, msg.action, self.action_topics[agent])

    # ---------------------------------------------------------------- messages out
    def _listeners(self) -> list[int]:
        now = time.monotonic()
        if now - self._listening_at > LISTENER_REFRESH_S:
            self._listening = [a for a, p in enumerate(self.agent_obs_pubs) if p.get_subscription_count() > 0]
            self._listening_at = now
        return self._listening

    def _publish_observations(self, result: StepResult, missing: np.ndarray | None = None) -> None:
        """Observations of the current step; ``missing`` (a mask): a re-send, only to the
        agents that have not answered yet (it also re-reads who listens)."""
        world = self.world
        if missing is not None:
            self._listening_at = -np.inf
        batch = AgentBatch.from_world(world, observations=result.observations, action_mask=result.action_mask)
        if self.observations_pub.get_subscription_count() > 0:
            train = world.training_action_mask(result.action_mask) if self.options.training_masks else None
            rows = None if missing is None else np.flatnonzero(missing)
            self.observations_pub.publish(convert.encode_observation_batch(
                batch, result.rewards, result.done, rows=rows, train_masks=train,
                encoding=self.options.observation_encoding))
        listening = self._listeners()
        if missing is not None:
            listening = [a for a in listening if missing[a]]
        if listening:
            rows = np.asarray(listening, dtype=np.int64)
            for a, msg in zip(listening, convert.encode_agent_observations(batch, result.rewards, result.done, rows)):
                self.agent_obs_pubs[a].publish(msg)

    def _publish_state(self, final: bool = False) -> None:
        """State and clock (volatile: built only while someone subscribes, as building the
        state costs more than the rest of a step's messages), viewers every k steps (latched:
        skipped while nobody subscribes, but the last step always goes out)."""
        world, every = self.world, self.options.viewer_every
        if self.state_pub.get_subscription_count():
            self.state_pub.publish(convert.encode_state(world, self.lockstep.missed))
        if self.clock_pub.get_subscription_count():
            self.clock_pub.publish(viewer_msgs.clock(world.t, self.options.dt))
        viewers = (self.score_pub, self.map_pub, self.markers_pub)
        if every > 0 and (final or world.t % every == 0 and any(p.get_subscription_count() for p in viewers)):
            stamp = viewer_msgs.sim_time(world.t, self.options.dt)
            self.score_pub.publish(Float64(data=world.score))
            self.map_pub.publish(viewer_msgs.occupancy_grid(world, stamp, self.metric_frame))
            self.markers_pub.publish(viewer_msgs.agent_markers(world, stamp, self.metric_frame))

    # ---------------------------------------------------------------------- waiting
    def _wait_for_subscribers(self, executor) -> None:
        """Before step 0: ``require_subscribers`` are heard, and the recorders matched everything."""
        publishers = {topics.STATE: self.state_pub, topics.APPLIED_ACTIONS: self.applied_pub,
                      topics.OBSERVATIONS: self.observations_pub, topics.SUMMARY: self.summary_pub,
                      topics.SCENARIO: self.scenario_pub, topics.SCORE: self.score_pub}
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
        while missing := [n for n in self.options.require_subscribers if publishers[n].get_subscription_count() == 0]:
            if time.monotonic() > deadline:
                self.get_logger().warning(
                    f"no subscriber on {missing} after {self.options.startup_timeout_s:g} s; starting anyway")
                return
            executor.spin_once(timeout_sec=0.05)
        expected = max(self.options.recorders, recorders_present(self))  # told about, or present at start
        self.ownership.expect_recorders(expected)
        publishers = [self.scenario_pub, self.summary_pub, self.state_pub, self.applied_pub, self.observations_pub,
                      self.score_pub, self.clock_pub, self.map_pub, self.markers_pub, *self.agent_obs_pubs,
                      *(self.robots.publishers if self.robots is not None else ())]
        if expected:
            self.get_logger().info(f"waiting for {expected} recorder(s) to match every topic")
            if not wait_for_recorders(self, executor, publishers, expected, self.recorder_reports,
                                      self.options.startup_timeout_s):
                self.get_logger().warning("the recorder has not matched every topic; starting anyway")
        self._listening_at = -np.inf  # re-read the per-agent listeners: the recorder is one

    def _linger(self, executor) -> None:
        """Keep the node up after the last messages until their readers have left (a host
        leaves once it has read the done observation), at most ``LINGER_S``: a process that
        exits at once sometimes takes its final samples with it (seen with the done
        observations). A reader that stays (a recorder, a viewer) gets the whole ``LINGER_S``."""
        until = time.monotonic() + LINGER_S
        streams = [self.observations_pub, self.score_pub, self.clock_pub, self.map_pub, self.markers_pub,
                   *self.agent_obs_pubs]
        while (now := time.monotonic()) < until and any(p.get_subscription_count() for p in streams):
            executor.spin_once(timeout_sec=min(LINGER_POLL_S, until - now))

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
        self._publish_state()
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
        self._publish_observations(self.result)
        self.settle()
        t0 = time.monotonic()
        resend = functools.partial(self._publish_observations, self.result)
        self.tick = self.lockstep.await_actions(executor, resend, self.started, self.tick)
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
        self._publish_observations(self.result)  # done=True: hosts stop answering
        self.settle()
        self._bar.close()
        self._count_pause()
        self.clock.update(ended=time.monotonic(), cpu_to=time.process_time(), started=self.started)
        if last:
            self._linger(executor)
        summary = self.lockstep.summary(self.book, self.scenario, self.options.policy_label or "unknown", self.clock)
        if self.robots is not None:
            summary.update(self.robots.summary())
        self.summary_pub.publish(String(data=json.dumps(summary, default=float)))
        for publisher in (self.applied_pub, self.state_pub, self.summary_pub) if last else ():
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
        self._publish_observations(dataclasses.replace(self.result, done=True))
        self._bar.close()
        self.get_logger().info(f"episode abandoned at step {self.world.t} of {self.scenario.config.episode_steps}")

    def _finish_step(self, book: EpisodeStats, t: int, actions: np.ndarray, loads_before: np.ndarray,
                     queued_before: np.ndarray, wait_s: float, step_s: float, final: bool) -> None:
        """Step ``t``'s bookkeeping and messages (applied actions, state, viewers). The world
        has not moved since step ``t``, so this runs after the next observations went out,
        while the agents think: off the lockstep's critical path."""
        book.record(t, self.world, loads_before, queued_before, wait_s, step_s)
        if self.applied_pub.get_subscription_count():  # volatile: nobody can read it later
            self.applied_pub.publish(convert.encode_applied(t, actions))
        self._publish_state(final=final)
        if self.view is not None:
            self.view.publish(self.world, final=final)


def serve_world(scenario: Scenario, options: WorldNodeOptions, domain_id: int | None = None,
                on_summary: Callable[[dict], None] | None = None, stay: bool = False,
                scenario_file: str = "") -> dict | None:
    """Run the world node in this process, controllable through simulation_interfaces
    (:mod:`formic_ros.sim_control`): it plays one episode and returns its summary, or, with
    ``options.paused``, waits for a client and serves episode after episode until told to quit
    (then the last summary, None if no episode ended). ``on_summary`` gets each summary as soon
    as its episode ends; with ``stay`` the node then keeps serving the latched scenario and
    summary until interrupted. ``scenario_file``: where ``scenario`` came from, if from a file
    (a reset loads it again)."""
    from .env import ros_session
    from .sim_control import SimulationControl
    from .world_lock import world_lock

    with world_lock(options.namespace, domain_id), ros_session(domain_id) as executor:
        node = WorldNode(scenario, options)
        executor.add_node(node)
        control = SimulationControl(node, executor, scenario_file, stays=options.paused or stay)
        try:
            return control.serve(on_summary)
        except KeyboardInterrupt:
            if stay and control.summary is not None:  # interrupting --stay after the episode is its normal end
                return control.summary
            raise
        finally:
            control.close()
            if node.view is not None:
                node.view.close()
