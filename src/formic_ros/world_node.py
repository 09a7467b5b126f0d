"""The world node: owns the simulation core and steps it with its agents over ROS.

Lockstep (default): publish the observations of step t, wait until every agent has answered
for step t or the step's deadline passes (a missing agent does nothing that step: NO_ACTION,
counted and logged), step, repeat. Free-running (``rate_hz``): step at a fixed rate with
whatever actions arrived, as a team of robots would. Either way, step 0 waits for every agent
(up to the start-up timeout) and re-sends its observations, so hosts that are still
discovering the graph do not start the episode behind.

Observations go out batched on ``observations`` when that topic has a subscriber, and per agent
on ``agent_K/observation`` only where that topic has one. Actions come in on ``actions``
(batches, any subset of agents) and ``agent_K/action``; every action is validated, and a bad
one is rejected with a (rate-limited) log line, never an exception.

Training mode (:func:`serve_training_world`): episode after episode on the scenarios the
in-process trainer would draw, with the training masks in the observation batches.
"""

from __future__ import annotations

import functools
import json
import sys
import time
from collections import Counter
from dataclasses import dataclass, replace
from typing import TYPE_CHECKING, Callable

import numpy as np
from formic_interfaces.msg import (
    ActionBatch,
    AgentAction,
    AgentObservation,
    ObservationBatch,
    ScenarioDescription,
    WorldState,
)
from rclpy.duration import Duration
from rclpy.node import Node
from std_msgs.msg import Float64, String

from formic_runtime.episode import EpisodeStats
from formic_world import NO_ACTION, Scenario, StepResult, World

from . import convert, qos

if TYPE_CHECKING:
    from formic_trainer.config import TrainConfig

RESEND_S = 0.5  # step-0 observations are re-sent this often until every agent has answered
STEP_RESEND_S = 0.25  # later steps: re-sent to the agents that have not answered after this long
LISTENER_REFRESH_S = 0.25  # how often the set of per-agent observation subscribers is re-read
LINGER_S = 0.5  # the node stays up this long after the episode's last messages
ACK_TIMEOUT_S = 3.5  # at the end, how long subscribers get to acknowledge the last messages
# (acknowledgements follow Fast DDS's heartbeats, about every 3 s, so this is only waited
# for when someone subscribes to the logged topics: a recorder, the planner, a viewer)


@dataclass(frozen=True)
class WorldNodeOptions:
    namespace: str = qos.DEFAULT_NAMESPACE
    deadline_s: float = 1.0  # lockstep: how long a step waits for the last action
    startup_timeout_s: float = 60.0  # how long step 0 waits for every agent
    rate_hz: float | None = None  # free-running: steps per second (no waiting for agents)
    viewer_every: int = 10  # map, markers and score every k steps (0: never)
    dt: float = 0.1  # simulated seconds per step (/clock)
    policy_label: str = ""  # which policies drive the team, for the scenario message and summary
    training_masks: bool = False  # fill ObservationBatch.train_masks (SPEC 4 filter)
    observation_encoding: str = "compact"  # ObservationBatch: "compact" (lossless, ~10x smaller) or "float32"
    require_subscribers: tuple[str, ...] = ()  # topics (e.g. "applied_actions") needing a subscriber before step 0
    progress: bool = False
    view_port: int | None = None  # live view (formic_view, Foxglove WebSocket) on this port; None: none


class RateLimitedLog:
    """Warnings grouped by reason, at most one line per reason per period, with a count of
    the ones held back (a flood of bad actions must not flood the log or slow the world)."""

    def __init__(self, logger, period_s: float = 2.0):
        self.logger = logger
        self.period_s = period_s
        self.last: dict[str, float] = {}
        self.held: Counter = Counter()

    def __call__(self, reason: str, detail: str) -> None:
        now = time.monotonic()
        if now - self.last.get(reason, -np.inf) < self.period_s:
            self.held[reason] += 1
            return
        more = self.held.pop(reason, 0)
        self.last[reason] = now
        self.logger.warning(f"{reason}: {detail}" + (f" (and {more} more since the last report)" if more else ""))


class ActionInbox:
    """The actions of the step the world is waiting on: validated, first answer wins. A late
    copy of an action the last closed step applied (a host answering a re-sent observation)
    is a harmless duplicate, not a rejection."""

    def __init__(self, n_agents: int, log: RateLimitedLog):
        self.n_agents = n_agents
        self.log = log
        self.step = -1
        self.is_open = False
        self.actions = np.full(n_agents, NO_ACTION, dtype=np.int64)
        self.received = np.zeros(n_agents, dtype=bool)
        self.rejected: Counter = Counter()
        self.duplicates = 0
        self.closed_step = -1
        self.closed_actions = np.full(n_agents, NO_ACTION, dtype=np.int64)

    def open(self, step: int) -> None:
        self.step, self.is_open = step, True
        self.actions[:] = NO_ACTION
        self.received[:] = False

    def close(self) -> np.ndarray:
        self.is_open = False
        self.closed_step = self.step
        self.closed_actions = self.actions.copy()
        return self.actions.copy()

    def reject(self, reason: str, count: int, detail: str) -> None:
        self.rejected[reason] += count
        self.log(f"rejected action ({reason})", detail)

    def offer_one(self, step: int, agent: int, action: int) -> None:
        """One agent's answer on its own topic (the common case, kept cheap)."""
        if step != self.step or not self.is_open or not 0 <= action <= 4 or self.received[agent]:
            self.offer(step, np.array([agent]), np.array([action]), qos.agent_topic(agent, qos.AGENT_ACTION))
            return
        self.actions[agent] = action
        self.received[agent] = True

    def offer(self, step: int, agent_ids: np.ndarray, actions: np.ndarray, source: str) -> None:
        """Take the valid entries of an answer for ``step``; reject and log the rest."""
        if len(agent_ids) != len(actions):
            self.reject("malformed", 1, f"{source}: {len(agent_ids)} agent ids but {len(actions)} actions")
            return
        if step != self.step or not self.is_open:
            ids = np.asarray(agent_ids, dtype=np.int64)
            if (step == self.closed_step and (ids < self.n_agents).all()
                    and (self.closed_actions[ids] == np.asarray(actions, dtype=np.int64)).all()):
                self.duplicates += len(ids)
                return
            reason = "old step" if step < self.step or (step == self.step and not self.is_open) else "future step"
            self.reject(reason, len(agent_ids), f"{source}: step {step}, the world is at step {self.step}")
            return
        ids = np.asarray(agent_ids, dtype=np.int64)
        acts = np.asarray(actions, dtype=np.int64)
        unknown = ids >= self.n_agents
        if unknown.any():
            self.reject("unknown agent", int(unknown.sum()),
                        f"{source}: agent ids {ids[unknown][:8].tolist()} (team of {self.n_agents})")
        bad = ~unknown & ((acts < 0) | (acts > 4))
        if bad.any():
            self.reject("action out of range", int(bad.sum()),
                         f"{source}: actions {acts[bad][:8].tolist()} for agents {ids[bad][:8].tolist()} (valid 0-4)")
        ok = ~unknown & ~bad
        ids, acts = ids[ok], acts[ok]
        fresh = ~self.received[ids]
        self.duplicates += int((~fresh).sum())
        self.actions[ids[fresh]] = acts[fresh]
        self.received[ids[fresh]] = True


class WorldNode(Node):
    """Node ``world`` in the ForMIC namespace; :meth:`run` plays one episode, :meth:`load`
    sets up the next (a new scenario for the same team size)."""

    def __init__(self, scenario: Scenario, options: WorldNodeOptions = WorldNodeOptions()):
        super().__init__("world", namespace=options.namespace)
        self.options = options
        n = self.n_agents = scenario.config.n_agents
        self.log = RateLimitedLog(self.get_logger())
        convert.encoding_code(options.observation_encoding)  # an unknown encoding fails here, not at step 0

        pub = self.create_publisher
        self.scenario_pub = pub(ScenarioDescription, qos.SCENARIO, qos.LATCHED)
        self.summary_pub = pub(String, qos.SUMMARY, qos.LATCHED)
        self.observations_pub = pub(ObservationBatch, qos.OBSERVATIONS, qos.STREAM)
        self.state_pub = pub(WorldState, qos.STATE, qos.LOG)
        self.applied_pub = pub(ActionBatch, qos.APPLIED_ACTIONS, qos.LOG)
        self.score_pub = pub(Float64, qos.SCORE, qos.LOG)
        self.clock_pub = pub(convert.Clock, qos.CLOCK, qos.LOG)
        self.map_pub = pub(convert.OccupancyGrid, qos.MAP, qos.VIEWER)
        self.markers_pub = pub(convert.MarkerArray, qos.AGENT_MARKERS, qos.VIEWER)
        self.agent_obs_pubs = [pub(AgentObservation, qos.agent_topic(a, qos.AGENT_OBSERVATION), qos.STREAM)
                               for a in range(n)]
        self.create_subscription(ActionBatch, qos.ACTIONS, self._on_action_batch, qos.STREAM)
        for a in range(n):
            self.create_subscription(AgentAction, qos.agent_topic(a, qos.AGENT_ACTION),
                                     lambda msg, a=a: self._on_agent_action(a, msg), qos.STREAM)
        self._listening: list[int] = []
        self._listening_at = -np.inf
        self.view = None  # the live view, fed after each step (formic_view; no ROS involved)
        if options.view_port is not None:
            from formic_view import LiveView, announcement

            self.view = LiveView(port=options.view_port, dt=options.dt)
            self.get_logger().info(announcement(self.view.url))
        self.load(scenario)

    def load(self, scenario: Scenario) -> None:
        """The scenario of the next episode, published (latched) at once."""
        n = scenario.config.n_agents
        if n != self.n_agents:
            raise ValueError(f"a world node serves one team size ({self.n_agents} agents), not {n}")
        self.scenario = scenario
        self.world = World(scenario)
        self.inbox = ActionInbox(n, self.log)
        self.missed = np.zeros(n, dtype=np.int64)
        self.last_answered = np.full(n, -1, dtype=np.int64)  # last step each agent answered in time
        self.scenario_pub.publish(convert.scenario_description(scenario, self.options.policy_label))

    # ------------------------------------------------------------------ actions in
    def _on_action_batch(self, msg: ActionBatch) -> None:
        ids = convert.read(msg.agent_ids, np.uint32)
        self.inbox.offer(msg.step, ids, convert.read(msg.actions, np.uint8), f"{qos.ACTIONS} ({len(ids)} agents)")

    def _on_agent_action(self, agent: int, msg: AgentAction) -> None:
        if msg.agent_id != agent:
            source = qos.agent_topic(agent, qos.AGENT_ACTION)
            self.inbox.reject("agent id mismatch", 1, f"{source}: message for agent {msg.agent_id}")
            return
        self.inbox.offer_one(msg.step, agent, msg.action)

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
        fields = dict(
            step=world.t, observations=result.observations, action_mask=result.action_mask,
            loads=world.loads, rewards=result.rewards, queued=world.queued, positions=world.pos,
            world_shape=world.grid.shape, done=result.done,
        )
        if self.observations_pub.get_subscription_count() > 0:
            train = world.training_action_mask(result.action_mask) if self.options.training_masks else None
            rows = None if missing is None else np.flatnonzero(missing)
            self.observations_pub.publish(convert.observation_batch(
                **fields, agent_ids=rows, train_masks=train, encoding=self.options.observation_encoding))
        listening = self._listeners()
        if missing is not None:
            listening = [a for a in listening if missing[a]]
        if listening:
            for a, msg in zip(listening, convert.agent_observations(agent_ids=listening, **fields)):
                self.agent_obs_pubs[a].publish(msg)

    def _publish_state(self, final: bool = False) -> None:
        """State and clock (volatile: built only while someone subscribes, as building the
        state costs more than the rest of a step's messages), viewers every k steps (latched:
        skipped while nobody subscribes, but the last step always goes out)."""
        world, every = self.world, self.options.viewer_every
        if self.state_pub.get_subscription_count():
            self.state_pub.publish(convert.world_state(world, self.missed))
        if self.clock_pub.get_subscription_count():
            self.clock_pub.publish(convert.clock(world.t, self.options.dt))
        viewers = (self.score_pub, self.map_pub, self.markers_pub)
        if every > 0 and (final or world.t % every == 0 and any(p.get_subscription_count() for p in viewers)):
            stamp = convert.sim_time(world.t, self.options.dt)
            self.score_pub.publish(Float64(data=world.score))
            self.map_pub.publish(convert.occupancy_grid(world, stamp))
            self.markers_pub.publish(convert.agent_markers(world, stamp))

    # ---------------------------------------------------------------------- waiting
    def _collect(self, executor, deadline: float, need_all: bool, resend=None, resend_s: float = RESEND_S) -> None:
        """Spin until every agent answered (``need_all``) or ``deadline`` (monotonic s);
        ``resend`` every ``resend_s`` meanwhile (an observation lost under load)."""
        next_resend = time.monotonic() + resend_s
        while not (need_all and self.inbox.received.all()):
            now = time.monotonic()
            if now >= deadline:
                return
            if resend is not None and now >= next_resend:
                resend()
                next_resend = now + resend_s
            executor.spin_once(timeout_sec=min(deadline - now, next_resend - now, 0.1))

    def _wait_for_subscribers(self, executor) -> None:
        """Before step 0: every topic in ``require_subscribers`` (a recorder's) has a subscriber."""
        publishers = {qos.STATE: self.state_pub, qos.APPLIED_ACTIONS: self.applied_pub,
                      qos.OBSERVATIONS: self.observations_pub, qos.SUMMARY: self.summary_pub,
                      qos.SCENARIO: self.scenario_pub, qos.SCORE: self.score_pub}
        deadline = time.monotonic() + self.options.startup_timeout_s
        while missing := [n for n in self.options.require_subscribers if publishers[n].get_subscription_count() == 0]:
            if time.monotonic() > deadline:
                self.get_logger().warning(
                    f"no subscriber on {missing} after {self.options.startup_timeout_s:g} s; starting anyway")
                return
            executor.spin_once(timeout_sec=0.05)

    def _linger(self, executor) -> None:
        """Keep the node up a moment after the last messages: a process that exits at once
        sometimes takes its final samples with it (seen with the done observations)."""
        until = time.monotonic() + LINGER_S
        while time.monotonic() < until:
            executor.spin_once(timeout_sec=max(0.0, until - time.monotonic()))

    def _count_misses(self, t: int) -> None:
        self.last_answered[self.inbox.received] = t
        missing = np.flatnonzero(~self.inbox.received)
        if len(missing):
            self.missed[missing] += 1
            self.log("missed actions", f"step {t}: no action in time from agents {missing[:16].tolist()}"
                     f"{' ...' if len(missing) > 16 else ''} ({int(self.missed.sum())} missed so far)")

    # -------------------------------------------------------------------- episode
    def _await_actions(self, executor, result: StepResult, started: float, tick: float) -> float:
        """Wait for the actions of the current step as the mode says; returns the free-running
        clock's tick (the moment this step is due)."""
        opts, now = self.options, time.monotonic()
        if self.inbox.step == 0:
            self._collect(executor, now + opts.startup_timeout_s, need_all=True,
                          resend=lambda: self._publish_observations(result, ~self.inbox.received))
            absent = int((~self.inbox.received).sum())
            self.get_logger().info(
                f"stepping: every agent answered step 0 after {time.monotonic() - started:.1f} s" if not absent else
                f"stepping: {absent} agents did not answer step 0 within {opts.startup_timeout_s:g} s"
            )
            return time.monotonic()
        if opts.rate_hz:
            tick = max(tick + 1.0 / opts.rate_hz, now)
            self._collect(executor, tick, need_all=False)
            return tick
        self._collect(executor, now + opts.deadline_s, need_all=True,
                      resend=lambda: self._publish_observations(result, ~self.inbox.received), resend_s=STEP_RESEND_S)
        return tick

    def run(self, executor, last: bool = True) -> dict:
        """Play the episode; returns the summary (also published, latched, on ``summary``).
        ``last``: the process leaves afterwards, so the final messages get time to go out."""
        from tqdm import tqdm

        opts, world, cfg = self.options, self.world, self.scenario.config
        horizon = cfg.episode_steps
        self._wait_for_subscribers(executor)
        result = world.last_result if world.t == 0 else world.reset(self.scenario)  # a new world is reset
        book = EpisodeStats(cfg.n_agents, horizon)
        self._publish_state()
        started = tick = time.monotonic()
        clock = {"stepping_from": started, "cpu_from": time.process_time()}
        deadline = f"lockstep, deadline {opts.deadline_s * 1e3:.0f} ms"
        mode = f"free-running at {opts.rate_hz} Hz" if opts.rate_hz else deadline
        self.get_logger().info(f"episode: {cfg.height}x{cfg.width}, {cfg.n_agents} agents, {horizon} steps, "
                               f"seed {self.scenario.seed}, {mode}")
        finish = None  # the last step's bookkeeping, done while the agents choose the next actions
        with tqdm(total=horizon, disable=not opts.progress, file=sys.stderr, unit="step", leave=False) as bar:
            for t in range(horizon):
                self.inbox.open(t)
                self._publish_observations(result)
                if finish is not None:
                    finish()
                t0 = time.monotonic()
                tick = self._await_actions(executor, result, started, tick)
                self._count_misses(t)
                actions = self.inbox.close()
                t1 = time.monotonic()
                loads_before, queued_before = world.loads.copy(), world.queued.copy()
                result = world.step(actions)
                finish = functools.partial(self._finish_step, book, t, actions, loads_before, queued_before,
                                           t1 - t0, time.monotonic() - t1, final=t + 1 == horizon)
                if t == 0:  # speed is measured from here: start-up and discovery excluded
                    clock = {"stepping_from": time.monotonic(), "cpu_from": time.process_time()}
                bar.update()
        self._publish_observations(result)  # done=True: hosts stop answering
        if finish is not None:
            finish()
        clock.update(ended=time.monotonic(), cpu_to=time.process_time(), started=started)
        if last:
            self._linger(executor)
        summary = self._summary(book, clock)
        self.summary_pub.publish(String(data=json.dumps(summary, default=float)))
        for publisher in (self.applied_pub, self.state_pub, self.summary_pub) if last else ():
            if publisher.get_subscription_count():
                publisher.wait_for_all_acked(Duration(seconds=ACK_TIMEOUT_S))
        self.get_logger().info(
            f"episode over: food {world.score:.1f}, {summary['missed_actions']} missed actions, "
            f"{sum(self.inbox.rejected.values())} rejected, {summary['steps_per_s']:.0f} steps/s"
        )
        return summary

    def _finish_step(self, book: EpisodeStats, t: int, actions: np.ndarray, loads_before: np.ndarray,
                     queued_before: np.ndarray, wait_s: float, step_s: float, final: bool) -> None:
        """Step ``t``'s bookkeeping and messages (applied actions, state, viewers). The world
        has not moved since step ``t``, so this runs after the next observations went out,
        while the agents think: off the lockstep's critical path."""
        book.record(t, self.world, loads_before, queued_before, wait_s, step_s)
        if self.applied_pub.get_subscription_count():  # volatile: nobody can read it later
            self.applied_pub.publish(convert.applied_actions(t, actions))
        self._publish_state(final=final)
        if self.view is not None:
            self.view.publish(self.world, final=final)

    def _summary(self, book: EpisodeStats, clock: dict) -> dict:
        """``formic sim``'s summary plus what the distributed run adds."""
        steps = self.scenario.config.episode_steps - 1  # timed steps (after step 0)
        stepping_s = clock["ended"] - clock["stepping_from"]
        summary = book.summary(self.scenario, self.options.policy_label or "unknown")
        summary.update(
            food_curve=book.food_curve.tolist(),
            missed_actions=int(self.missed.sum()),
            missed_per_agent=self.missed.tolist(),
            last_answered_step=self.last_answered.tolist(),
            rejected_actions=dict(self.inbox.rejected),
            mode="free-running" if self.options.rate_hz else "lockstep",
            steps_per_s=steps / stepping_s if steps > 0 and stepping_s > 0 else 0.0,
            startup_s=clock["stepping_from"] - clock["started"],
            wall_s=clock["ended"] - clock["started"],
            world_cpu_ms_per_step=(clock["cpu_to"] - clock["cpu_from"]) / max(1, steps) * 1e3,
        )
        return summary


def require_one_world(cfg: TrainConfig) -> None:
    """A world node serves one world: distributed training needs one meta-agent team."""
    if len(cfg.teams) != 1:
        raise ValueError(f"distributed training runs one meta-agent world; teams={list(cfg.teams)} "
                         "(set one team size, e.g. --set teams=16)")


def serve_training_world(
    cfg: TrainConfig,
    episodes: int,
    options: WorldNodeOptions,
    first_episode: int = 0,
    domain_id: int | None = None,
    on_episode: Callable[[dict], None] | None = None,
) -> list[dict]:
    """Distributed training's world: ``episodes`` episodes, each on a new scenario drawn as the
    in-process trainer draws them (:func:`formic_trainer.worlds.sample_scenarios` from the
    run's scenario stream at ``first_episode``: world size, obstacles, curriculum intensities,
    training start), with the training masks in the observations. One meta-agent world: the
    configuration's ``teams`` must hold one team. ``on_episode`` gets each episode's summary
    (with ``episode``, the global episode number, and the curriculum's intensities)."""
    from formic_trainer.worlds import sample_scenarios, scenario_rng

    from .env import ros_session

    require_one_world(cfg)
    options = replace(options, training_masks=True, policy_label=options.policy_label or "formic:learning")
    rng = scenario_rng(cfg, first_episode)
    summaries = []
    with ros_session(domain_id) as executor:
        node = None
        for episode in range(first_episode, first_episode + episodes):
            (scenario,), highway, deposit = sample_scenarios(cfg, rng, episode)
            if node is None:
                node = WorldNode(scenario, options)
                executor.add_node(node)
            else:
                node.load(scenario)
            summary = node.run(executor, last=episode + 1 == first_episode + episodes)
            summary.update(episode=episode, highway_intensity=highway, deposit_strength=deposit)
            summaries.append(summary)
            if on_episode is not None:
                on_episode(summary)
    return summaries


def serve_world(
    scenario: Scenario,
    options: WorldNodeOptions,
    domain_id: int | None = None,
    on_summary: Callable[[dict], None] | None = None,
    stay: bool = False,
) -> dict:
    """Run the world node for one episode in this process. ``on_summary`` gets the summary as
    soon as the episode ends; with ``stay`` the node then keeps serving the latched scenario
    and summary until interrupted."""
    from .env import ros_session

    with ros_session(domain_id) as executor:
        node = WorldNode(scenario, options)
        executor.add_node(node)
        try:
            summary = node.run(executor)
        finally:
            if node.view is not None:
                node.view.close()
        if on_summary is not None:
            on_summary(summary)
        try:
            while stay:
                executor.spin_once(timeout_sec=0.2)
        except KeyboardInterrupt:
            pass
        return summary
