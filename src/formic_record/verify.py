"""``formic replay --verify``: the file's CRCs, then every message the world published,
re-simulated from the recorded scenario and applied actions and compared field by field
(:mod:`formic_record.checks`): per-agent and batched observations, world states, ``/clock``,
score, map and agent markers. The first mismatch of each topic is reported, with a count.

Messages without a step (clock, score, map, markers) are placed by what the world does: a
``/clock``, a map and the markers carry the sim time of their step, and a clock goes out with
each state (so clocks go forward): placed by value, not by counting, a lost message shifts no
other. A score goes out with each map: the k-th score is the k-th map's when their numbers agree.

A recording that stops before its episode's end (the run or the recorder was interrupted)
verifies up to its last complete step: the re-simulation runs while applied actions are
recorded, and what the recorder holds of later steps (each topic has its own reader, so a
recorder stopped mid-step holds some of the next steps' messages and not others) is counted,
not checked. Applied actions missing between recorded ones, or at the end of an episode whose
summary the world published, fail a recording the writer closed.
"""

from __future__ import annotations

import os
from collections import Counter, defaultdict
from dataclasses import asdict, dataclass, field
from itertools import pairwise

from formic_topics import (AGENT_OBSERVATION_TYPE, CLOCK_TYPE, FLOAT64_TYPE, MARKER_ARRAY_TYPE, OBSERVATION_BATCH_TYPE,
                           OCCUPANCY_GRID_TYPE, SCENARIO_TYPE, SCORE, WORLD_STATE_TYPE)
from formic_world import World

from . import checks
from .reading import Recording
from .replay import RecordedEpisode, read_episodes, resimulate

STEPPED = {AGENT_OBSERVATION_TYPE: checks.check_agent_observation,
           OBSERVATION_BATCH_TYPE: checks.check_observation_batch, WORLD_STATE_TYPE: checks.check_state}
STAMPED = {OCCUPANCY_GRID_TYPE: checks.check_map, MARKER_ARRAY_TYPE: checks.check_markers}
SCORE_SUFFIX = f"/{SCORE}"
DEFAULT_DT = 0.1  # `formic world --dt`'s default, for a recording with too few clocks to tell


@dataclass
class VerifyReport:
    ok: bool
    episodes: int
    states_checked: int
    steps_simulated: int
    reading: str  # how the recording was read
    problems: list[str] = field(default_factory=list)
    messages_checked: int = 0
    topics_checked: int = 0
    mismatches: dict[str, dict] = field(default_factory=dict)  # topic -> first, count
    interrupted_at: int | None = None  # the last complete step of a recording cut before its episode's end

    def mismatch(self, topic: str, step: int | None, detail: str) -> None:
        entry = self.mismatches.setdefault(topic, {"step": step, "first": detail, "count": 0})
        entry["count"] += 1
        self.ok = False

    def fail(self, problem: str) -> None:
        self.problems.append(problem)
        self.ok = False

    def summary(self) -> str:
        if not self.ok:
            where = [f"{t}: mismatch at step {m['step']}: {m['first']} ({m['count']} mismatching message(s))"
                     for t, m in self.mismatches.items()]
            return "FAILED: " + "; ".join(where + self.problems) + f" ({self.reading})"
        text = (f"OK: {self.messages_checked} recorded messages on {self.topics_checked} topics match the "
                f"re-simulation bit for bit ({self.states_checked} recorded states, {self.steps_simulated} "
                f"steps, {self.episodes} episode(s); {self.reading})")
        return text + ("; note: " + "; ".join(self.problems) if self.problems else "")

    def to_dict(self) -> dict:
        return asdict(self)


def _infer_dt(clocks: dict, run_info: dict) -> float:
    """Seconds a step: recorded, else the most common difference of consecutive clocks."""
    if "dt" in run_info:
        return float(run_info["dt"])
    steps = Counter(later - earlier for items in clocks.values()
                    for earlier, later in pairwise(checks.stamp_ns(msg.clock) for _, msg in items) if later > earlier)
    return steps.most_common(1)[0][0] / 1e9 if steps else DEFAULT_DT


def _step_of(stamp, dt: float) -> int | None:
    """The step whose sim time ``stamp`` is, or None when it is no step's."""
    if stamp is None:
        return None
    step = round(checks.stamp_ns(stamp) / (dt * 1e9))
    return step if checks.stamp_ns(stamp) == checks.sim_time_ns(step, dt) else None


def _collect(recording: Recording, report: VerifyReport):
    """Every checkable message, decoded, as pending[episode][step] -> [(topic, check, msg)]."""
    store = recording.typestore()
    kinds = set(STEPPED) | set(STAMPED) | {CLOCK_TYPE, SCENARIO_TYPE}
    wanted = [t for t, i in recording.topics.items()
              if i.msgtype in kinds or (i.msgtype == FLOAT64_TYPE and t.endswith(SCORE_SUFFIX))]
    pending: dict[int, dict[int, list]] = defaultdict(lambda: defaultdict(list))
    clocks, stamped, scores = (defaultdict(list) for _ in range(3))
    episode, described = 0, False
    for message in recording.messages(wanted):
        try:
            msg = store.deserialize_cdr(message.data, message.msgtype)
        except Exception as exc:  # noqa: BLE001 - a payload that no longer decodes is a mismatch
            report.mismatch(message.topic, None, f"does not decode ({exc.__class__.__name__})")
            continue
        kind, topic = message.msgtype, message.topic
        if kind == SCENARIO_TYPE:
            episode, described = (episode + 1 if described else episode), True
        elif kind in STEPPED:
            pending[episode][int(msg.step)].append((topic, STEPPED[kind], msg))
        elif kind == CLOCK_TYPE:
            clocks[episode].append((topic, msg))
        elif kind in STAMPED:
            stamp = msg.header.stamp if kind == OCCUPANCY_GRID_TYPE else (
                msg.markers[0].header.stamp if len(msg.markers) else None)
            stamped[episode].append((topic, STAMPED[kind], msg, stamp))
        else:
            scores[episode].append((topic, msg))
    dt = _infer_dt(clocks, recording.run_info)
    for ep, items in clocks.items():
        last = -1
        for topic, msg in items:
            step = _step_of(msg.clock, dt)
            if step is None or step <= last:
                report.mismatch(topic, step, f"clock: {checks.stamp_ns(msg.clock)} ns is not the sim time of a "
                                f"step (dt {dt})" if step is None else f"clock: step {step} after step {last}")
                continue
            last = step
            pending[ep][step].append((topic, lambda m, w: checks.check_clock(m, w.t, dt), msg))
    maps: dict[tuple[int, int], object] = {}  # (episode, step) -> its map: the markers' frame
    for ep, items in stamped.items():
        steps = []
        for topic, check, msg, stamp in items:
            step = _step_of(stamp, dt)
            if step is None:
                report.mismatch(topic, step, "header.stamp is not the sim time of a step")
                continue
            if check is checks.check_markers:
                key = (ep, step)
                check = lambda m, w, key=key: checks.check_markers(  # noqa: E731
                    m, w, checks.map_frame(maps[key], w) if key in maps else None)
            pending[ep][step].append((topic, check, msg))
            if check is checks.check_map:
                steps.append(step)
                maps[(ep, step)] = msg
        if scores[ep] and len(scores[ep]) != len(steps):  # a map lost (latched, depth 1) or cut off
            report.problems.append(f"{len(scores[ep])} score messages but {len(steps)} maps: scores not checked")
            continue
        for (topic, msg), step in zip(scores[ep], steps):
            pending[ep][step].append((topic, lambda m, w: checks._scalars([("data", m.data, w.score, float)]), msg))
    return pending


def _check_end(report: VerifyReport, where: str, episode: RecordedEpisode, world: World, todo: dict,
               cut_short: bool) -> None:
    """What the end of an episode's re-simulation at ``world.t`` makes of the messages left in
    ``todo`` (those of later steps): past the episode's end they fail; after a gap in the applied
    actions, or when the world finished the episode, they fail unless the file was cut short
    (its lost chunks explain them); otherwise the recording was interrupted there."""
    steps = f"step {min(todo)}" if len(todo) == 1 else f"steps {min(todo, default=0)}-{max(todo, default=0)}"
    left = f"{sum(map(len, todo.values()))} recorded message(s) of {steps}" if todo else ""
    if world.done:
        if todo:
            report.fail(f"{where}{left} lie past the episode's end (step {world.t})")
        return
    later = sorted(t for t in episode.actions if t > world.t)
    lost = report.problems.append if cut_short else report.fail
    if later:
        lost(f"{where}no applied actions for step {world.t} but for {len(later)} later step(s) from step "
             f"{later[0]}: {left or 'nothing'} after it cannot be re-simulated")
    elif episode.finished:
        lost(f"{where}applied actions end at step {world.t} of {world.config.episode_steps}, but the world "
             "finished the episode (its summary is recorded)")
    else:
        report.interrupted_at = world.t
        report.problems.append(f"{where}recording ends at step {world.t} of {world.config.episode_steps} "
                               "(interrupted)" + (f"; {left} after it not checked" if todo else ""))


def verify_recording(path: str | os.PathLike) -> VerifyReport:
    """Check every CRC (a corrupted file raises :class:`RecordingError`), then re-simulate
    every episode and compare every recorded message the world published. A recording cut
    before its episode's end verifies up to its last complete step (see the module)."""
    recording = Recording(path)
    recording.check()
    episodes = read_episodes(recording)
    report = VerifyReport(True, len(episodes), 0, 0, recording.describe())
    if not episodes:
        report.fail("no scenario, state or applied actions in the recording")
    pending = _collect(recording, report)
    topics = set()
    for number, episode in enumerate(episodes):
        where = f"episode {number}: " if len(episodes) > 1 else ""
        todo = pending.get(number, {})
        try:
            for world in resimulate(episode):
                report.steps_simulated += int(world.t > 0)
                for topic, check, msg in todo.pop(world.t, ()):
                    report.messages_checked += 1
                    report.states_checked += check is checks.check_state
                    topics.add(topic)
                    difference = check(msg, world)
                    if difference:
                        report.mismatch(topic, world.t, difference)
        except ValueError as exc:
            report.fail(f"{where}{exc}")
            continue
        _check_end(report, where, episode, world, todo, recording.cut_short)
    report.topics_checked = len(topics)
    if report.ok and report.states_checked == 0:
        report.fail("no recorded state could be checked" + (
            ": the world never stepped (no applied actions; did any agent answer step 0?)"
            if not any(episode.actions for episode in episodes) else ""))
    return report
