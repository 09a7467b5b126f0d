"""Lockstep bookkeeping of the world node, without ROS wiring: the actions of the step waited
on (:class:`ActionInbox`: validated, first answer wins), how long a step waits (deadline,
start-up, free-running rate) and when it re-sends its observations (:class:`Lockstep`), who
missed which step, and rate-limited warnings about all of it."""

from __future__ import annotations

import time
from collections import Counter
from typing import Callable

import numpy as np

from formic_runtime.team import format_ids
import formic_topics as topics
from formic_world.geometry import NO_ACTION

from ..errors import NobodyJoined

RESEND_S = 0.1  # step-0 observations are re-sent this often until every agent has answered
# (the first is often lost: published when the world saw a reader that had not yet matched it)
STEP_RESEND_S = 0.25  # later steps: re-sent to the agents that have not answered after this long
INTAKE_WAIT_S = 0.002  # waiting for per-agent actions, the executor's other events are handled this often


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

    def __init__(self, n_agents: int, log: RateLimitedLog, owners=None):
        self.n_agents = n_agents
        self.log = log
        self.step = -1
        self.is_open = False
        self.actions = np.full(n_agents, NO_ACTION, dtype=np.int64)
        self.received = np.zeros(n_agents, dtype=bool)
        self.heard = 0  # how many of ``received`` are set (the wait loop reads it after every message)
        self.rejected: Counter = Counter()
        self.duplicates = 0
        self.closed_step = -1
        self.closed_actions = np.full(n_agents, NO_ACTION, dtype=np.int64)
        self.owners = owners  # the world's Ownership (allowed(topic, agent), allowed_batch(topic, ids)); None: anyone

    def open(self, step: int) -> None:
        """Wait on ``step``'s actions. Opening the step already open keeps the answers taken
        (a paused world opens its next step early: :meth:`WorldNode.pause`)."""
        if self.is_open and self.step == step:
            return
        self.step, self.is_open = step, True
        self.actions[:] = NO_ACTION
        self.received[:] = False
        self.heard = 0

    def close(self) -> np.ndarray:
        self.is_open = False
        self.closed_step = self.step
        self.closed_actions = self.actions.copy()
        return self.actions.copy()

    def reject(self, reason: str, count: int, detail: str) -> None:
        self.rejected[reason] += count
        self.log(f"rejected action ({reason})", detail)

    def offer_one(self, step: int, agent: int, action: int, via: str = "") -> None:
        """One agent's answer on its own topic (the common case, kept cheap)."""
        if step != self.step or not self.is_open or not 0 <= action <= 4 or self.received[agent]:
            self.offer(step, np.array([agent]), np.array([action]), topics.agent_topic(agent, topics.AGENT_ACTION), via)
            return
        if self.owners is not None and not self.owners.allowed(via, agent):
            return
        self.actions[agent] = action
        self.received[agent] = True
        self.heard += 1

    def offer_many(self, agents: np.ndarray, steps: np.ndarray, actions: np.ndarray, vias: list[str]) -> np.ndarray:
        """Many agents' answers, each on its own topic (``vias[agent]``), taken at once: what
        :meth:`offer_one` does for each, for the common case. Returns the mask of those left to
        :meth:`offer_one` (another step, an action out of range, an agent already heard, a second
        answer of one agent among them)."""
        fresh = (steps == self.step) & self.is_open & (actions <= 4) & ~self.received[agents]
        first = np.zeros(len(agents), dtype=bool)
        first[np.unique(agents, return_index=True)[1]] = True
        fresh &= first
        taken = fresh.copy()
        if self.owners is not None:  # one by one: each agent has its own topic (and owner)
            for i in np.flatnonzero(fresh).tolist():
                agent = int(agents[i])
                taken[i] = self.owners.allowed(vias[agent], agent)
        self.actions[agents[taken]] = actions[taken]
        self.received[agents[taken]] = True
        self.heard += int(taken.sum())
        return ~fresh

    def offer(self, step: int, agent_ids: np.ndarray, actions: np.ndarray, source: str, via: str = "") -> None:
        """Take the valid entries of an answer for ``step``; reject and log the rest."""
        if len(agent_ids) != len(actions):
            self.reject("malformed", 1, f"{source}: {len(agent_ids)} agent ids but {len(actions)} actions")
            return
        ids = np.asarray(agent_ids, dtype=np.int64)
        acts = np.asarray(actions, dtype=np.int64)
        if step != self.step or not self.is_open:
            if (step == self.closed_step and (ids < self.n_agents).all()
                    and (self.closed_actions[ids] == acts).all()):
                self.duplicates += len(ids)
                return
            reason = "old step" if step < self.step or (step == self.step and not self.is_open) else "future step"
            self.reject(reason, len(ids), f"{source}: step {step}, the world is at step {self.step}")
            return
        ok = (ids < self.n_agents) & (acts >= 0) & (acts <= 4)
        if not ok.all():  # unknown agents or bad actions: reported, the rest taken
            unknown = ids >= self.n_agents
            if unknown.any():
                self.reject("unknown agent", int(unknown.sum()),
                            f"{source}: agent ids {ids[unknown][:8].tolist()} (team of {self.n_agents})")
            bad = ~unknown & ~ok
            if bad.any():
                self.reject("action out of range", int(bad.sum()), f"{source}: actions {acts[bad][:8].tolist()} "
                            f"for agents {ids[bad][:8].tolist()} (valid 0-4)")
        if self.owners is not None and ok.any():
            ok[ok] = self.owners.allowed_batch(via, ids[ok])
        if not ok.all():
            ids, acts = ids[ok], acts[ok]
        fresh = ~self.received[ids]
        if not fresh.all():  # the common case (a whole batch, none heard yet) skips this
            self.duplicates += int((~fresh).sum())
            ids, acts = ids[fresh], acts[fresh]
        self.actions[ids] = acts
        self.received[ids] = True
        self.heard = int(self.received.sum())


class Lockstep:
    """One episode's exchange: the inbox, the waiting (``collect`` spins the executor until
    every agent answered or the deadline passes, calling ``resend`` meanwhile) and the misses.
    ``owners``: the inbox's gate; ``why_absent``: the "nobody joined" error's explanation."""

    def __init__(self, n_agents: int, log: RateLimitedLog, logger, deadline_s: float, startup_timeout_s: float,
                 rate_hz: float | None, allow_empty: bool = False, owners=None,
                 why_absent: Callable[[], str | None] | None = None,
                 take_actions: Callable[[float], bool] | None = None):
        self.log, self.logger, self.allow_empty = log, logger, allow_empty
        self.deadline_s, self.startup_timeout_s, self.rate_hz = deadline_s, startup_timeout_s, rate_hz
        self.inbox = ActionInbox(n_agents, log, owners)
        self.missed = np.zeros(n_agents, dtype=np.int64)
        self.last_answered = np.full(n_agents, -1, dtype=np.int64)  # last step each agent answered in time
        self.why_absent = why_absent
        self.take_actions = take_actions  # (timeout s) -> False when no per-agent action is expected

    def collect(self, executor, deadline: float, need_all: bool,
                resend: Callable[[np.ndarray], None] | None = None, resend_s: float = RESEND_S) -> None:
        """Spin until every agent answered (``need_all``) or ``deadline`` (monotonic s);
        ``resend(missing)`` every ``resend_s`` meanwhile (an observation lost under load;
        ``missing``: a mask of the agents that have not answered). While per-agent actions are
        expected, ``take_actions`` takes them and waits for them, and between its waits the
        executor runs the events that are ready (``executor.spin_ready``, at least every
        ``INTAKE_WAIT_S``)."""
        next_resend = time.monotonic() + resend_s
        inbox = self.inbox
        spun = time.monotonic()  # when the executor last ran
        while not (need_all and inbox.heard == inbox.n_agents):
            now = time.monotonic()
            if now >= deadline:
                return
            if resend is not None and now >= next_resend:
                resend(~self.inbox.received)
                next_resend = now + resend_s
            wait = min(deadline - now, next_resend - now, 0.1)
            if self.take_actions is None or not self.take_actions(min(wait, INTAKE_WAIT_S)):
                executor.spin_once(timeout_sec=wait)
                spun = time.monotonic()
            elif time.monotonic() - spun >= INTAKE_WAIT_S and not (need_all and inbox.heard == inbox.n_agents):
                executor.spin_ready()  # not when the step is complete: it costs ~90 µs
                spun = time.monotonic()

    def await_actions(self, executor, resend: Callable[[np.ndarray], None], started: float,
                      tick: float) -> float:
        """Wait for the actions of the open step as the mode says (``resend(missing)``: the
        current observations to the agents that have not answered); returns the free-running
        clock's tick (the moment this step is due)."""
        now = time.monotonic()
        if self.inbox.step == 0:
            self.collect(executor, now + self.startup_timeout_s, need_all=True, resend=resend)
            absent = np.flatnonzero(~self.inbox.received)
            if len(absent) and not self.allow_empty:
                raise NobodyJoined(self._absent_error(absent.tolist()))
            self.logger.info(
                f"stepping: every agent answered step 0 after {time.monotonic() - started:.1f} s" if not len(absent)
                else f"stepping: agents {format_ids(absent.tolist())} did not answer step 0 within "
                     f"{self.startup_timeout_s:g} s (--allow-empty)"
            )
            return time.monotonic()
        if self.rate_hz:
            tick = max(tick + 1.0 / self.rate_hz, now)
            self.collect(executor, tick, need_all=False)
            return tick
        self.collect(executor, now + self.deadline_s, need_all=True, resend=resend, resend_s=STEP_RESEND_S)
        return tick

    def _absent_error(self, absent: list[int]) -> str:
        """Why step 0 cannot start: who did not answer, and the likely causes. Only at step 0:
        a driver that vanishes later costs its agents a deadline a step, and the run goes on."""
        waited = f"within {self.startup_timeout_s:g} s"
        if len(absent) == len(self.inbox.received):
            why = self.why_absent() if self.why_absent is not None else None
            return f"no agent answered step 0 {waited}: " + (why or (
                "no agent host or agent node joined (check --domain-id, --namespace and "
                "ROS_AUTOMATIC_DISCOVERY_RANGE; --allow-empty runs the world without agents)"))
        return (f"agents {format_ids(absent)} did not answer step 0 {waited}: their drivers are missing. Likely "
                "causes: a driver on another ROS_DOMAIN_ID (--domain-id), in another --namespace, or out of "
                "discovery range (ROS_AUTOMATIC_DISCOVERY_RANGE, ROS_STATIC_PEERS); --allow-empty steps on without them")

    def summary(self, book, scenario, label: str, clock: dict) -> dict:
        """``formic sim``'s summary (``book``: the episode's :class:`EpisodeStats`) plus what
        the distributed run adds: misses, rejections, mode and speed (``clock``: monotonic and
        CPU times of the start, the first step and the end, and the seconds a simulation client
        held the world paused after the first step, which do not count as stepping)."""
        steps = scenario.config.episode_steps - 1  # timed steps (after step 0)
        stepping_s = clock["ended"] - clock["stepping_from"] - clock.get("paused_s", 0.0)
        return book.summary(scenario, label) | dict(
            food_curve=book.food_curve.tolist(),
            missed_actions=int(self.missed.sum()),
            missed_per_agent=self.missed.tolist(),
            last_answered_step=self.last_answered.tolist(),
            rejected_actions=dict(self.inbox.rejected),
            mode="free-running" if self.rate_hz else "lockstep",
            steps_per_s=steps / stepping_s if steps > 0 and stepping_s > 0 else 0.0,
            startup_s=clock["stepping_from"] - clock["started"],
            paused_s=clock.get("paused_s", 0.0),
            wall_s=clock["ended"] - clock["started"],
            world_cpu_ms_per_step=(clock["cpu_to"] - clock["cpu_from"]) / max(1, steps) * 1e3,
        )

    def count_misses(self, t: int) -> None:
        self.last_answered[self.inbox.received] = t
        missing = np.flatnonzero(~self.inbox.received)
        if len(missing):
            self.missed[missing] += 1
            self.log("missed actions", f"step {t}: no action in time from agents {missing[:16].tolist()}"
                     f"{' ...' if len(missing) > 16 else ''} ({int(self.missed.sum())} missed so far)")
