"""``formic replay --verify``: the file's CRCs, then every message the world published,
re-simulated from the recorded scenario and applied actions and compared field by field
(:mod:`formic_record.checks`): per-agent and batched observations, world states, ``/clock``,
score, map and agent markers. The first mismatch of each topic is reported, with a count.

Messages without a step (clock, score, map, markers) are placed by what the world does: a
``/clock`` goes out with each state (the k-th clock of an episode belongs to its k-th state),
map and markers carry the sim time of their step, and a score goes out with each map.
"""

from __future__ import annotations

import os
from collections import Counter, defaultdict
from dataclasses import asdict, dataclass, field

from . import checks
from .reading import Recording
from .replay import SCENARIO_TYPE, read_episodes, resimulate

STEPPED = {checks.AGENT_OBSERVATION: checks.check_agent_observation,
           checks.OBSERVATION_BATCH: checks.check_observation_batch, checks.WORLD_STATE: checks.check_state}
STAMPED = {checks.OCCUPANCY_GRID: checks.check_map, checks.MARKER_ARRAY: checks.check_markers}
SCORE_SUFFIX = "/score"


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

    def mismatch(self, topic: str, step: int | None, detail: str) -> None:
        entry = self.mismatches.setdefault(topic, {"step": step, "first": detail, "count": 0})
        entry["count"] += 1
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


def _infer_dt(clocks: dict, state_steps: dict, run_info: dict) -> float | None:
    if "dt" in run_info:
        return float(run_info["dt"])
    ratios = Counter(round(checks.stamp_ns(msg.clock) / step) for ep, items in clocks.items()
                     for (_, msg), step in zip(items, state_steps[ep]) if step > 0)
    return ratios.most_common(1)[0][0] / 1e9 if ratios else None


def _collect(recording: Recording, report: VerifyReport):
    """Every checkable message, decoded, as pending[episode][step] -> [(topic, check, msg)]."""
    store = recording.typestore()
    kinds = set(STEPPED) | set(STAMPED) | {checks.CLOCK, SCENARIO_TYPE}
    wanted = [t for t, i in recording.topics.items()
              if i.msgtype in kinds or (i.msgtype == checks.FLOAT64 and t.endswith(SCORE_SUFFIX))]
    pending: dict[int, dict[int, list]] = defaultdict(lambda: defaultdict(list))
    state_steps, clocks, stamped, scores = (defaultdict(list) for _ in range(4))
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
            if kind == checks.WORLD_STATE:
                state_steps[episode].append(int(msg.step))
        elif kind == checks.CLOCK:
            clocks[episode].append((topic, msg))
        elif kind in STAMPED:
            stamp = msg.header.stamp if kind == checks.OCCUPANCY_GRID else (
                msg.markers[0].header.stamp if len(msg.markers) else None)
            stamped[episode].append((topic, STAMPED[kind], msg, stamp))
        else:
            scores[episode].append((topic, msg))
    dt = _infer_dt(clocks, state_steps, recording.run_info)
    for ep, items in clocks.items():
        for k, (topic, msg) in enumerate(items):
            if k >= len(state_steps[ep]):
                report.mismatch(topic, None, f"clock message {k} has no recorded state to belong to")
            else:
                pending[ep][state_steps[ep][k]].append((topic, lambda m, w: checks.check_clock(m, w.t, dt), msg))
    for ep, items in stamped.items():
        steps = []
        for topic, check, msg, stamp in items:
            step = None if stamp is None or not dt else round(checks.stamp_ns(stamp) / (dt * 1e9))
            if step is None or checks.stamp_ns(stamp) != checks.sim_time_ns(step, dt):
                report.mismatch(topic, step, "header.stamp is not the sim time of a step")
                continue
            pending[ep][step].append((topic, check, msg))
            if check is checks.check_map:
                steps.append(step)
        if scores[ep] and len(scores[ep]) != len(steps):
            report.problems.append(f"{len(scores[ep])} score messages but {len(steps)} maps: scores not checked")
            continue
        for (topic, msg), step in zip(scores[ep], steps):
            pending[ep][step].append((topic, lambda m, w: checks._scalars([("data", m.data, w.score, float)]), msg))
    return pending


def verify_recording(path: str | os.PathLike) -> VerifyReport:
    """Check every CRC (a corrupted file raises :class:`RecordingError`), then re-simulate
    every episode and compare every recorded message the world published. Messages that
    cannot be reached (their actions are missing) fail a complete recording, and are only
    noted for one cut short (its tail is lost by definition)."""
    recording = Recording(path)
    recording.check()
    episodes = read_episodes(recording)
    report = VerifyReport(True, len(episodes), 0, 0, recording.describe())
    if not episodes:
        report.ok = False
        report.problems.append("no scenario, state or applied actions in the recording")
    pending = _collect(recording, report)
    topics = set()
    for number, episode in enumerate(episodes):
        label = f"episode {number}" if len(episodes) > 1 else "episode"
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
            report.ok = False
            report.problems.append(f"{label}: {exc}")
            continue
        if todo:
            count = sum(len(v) for v in todo.values())
            what = (f"{label}: {count} recorded messages of steps {min(todo)}-{max(todo)} cannot be "
                    f"re-simulated (no applied actions for step {world.t})")
            report.problems.append(what)
            report.ok = report.ok and recording.cut_short
    report.topics_checked = len(topics)
    if report.ok and report.states_checked == 0:
        report.ok = False
        report.problems.append("no recorded state could be checked")
    return report
