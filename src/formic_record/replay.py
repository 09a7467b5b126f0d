"""Replaying recordings: re-simulate to verify, render or view (republishing, which needs
rclpy, is :func:`formic_ros.recording.recorder.republish`).

The core is deterministic, so the recorded scenario and the actions the world applied
(``applied_actions``, 255 = none arrived) reproduce every state: verification
(:mod:`formic_record.verify`) re-simulates with :class:`formic_world.World` and compares every
message the world published field by field. Messages are decoded with the recording's own schemas.
"""

from __future__ import annotations

import json
import os
import time
from collections import deque
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from formic_topics import (ACTION_BATCH_TYPE, APPLIED_ACTIONS, NO_ACTION_WIRE, SCENARIO_TYPE, STRING_TYPE, SUMMARY,
                           WORLD_STATE_TYPE)
from formic_world import NO_ACTION, Scenario, World

from .reading import Recording

APPLIED_SUFFIX = f"/{APPLIED_ACTIONS}"
SUMMARY_SUFFIX = f"/{SUMMARY}"  # the world's, once it has played an episode to the end


@dataclass
class RecordedState:
    digest: str
    score: float
    rows: np.ndarray
    cols: np.ndarray

    @classmethod
    def from_message(cls, msg) -> "RecordedState":
        """A WorldState message (rosbags' or rclpy's) as what verification compares."""
        return cls(msg.state_digest, float(msg.score), np.asarray(msg.agent_rows), np.asarray(msg.agent_cols))


@dataclass
class RecordedEpisode:
    """One scenario and what the world applied and reached, keyed by step."""

    scenario: Scenario | None = None
    policies: str = ""
    actions: dict[int, np.ndarray] = field(default_factory=dict)  # step -> rows (agent ids, actions), -1 = none
    states: dict[int, RecordedState] = field(default_factory=dict)  # world.t -> state
    finished: bool = False  # the world's summary of this episode is recorded: the world played it to the end


def _summary_seed(text: str) -> int | None:
    """The seed a world summary (JSON) names; None when it names none."""
    try:
        return int(json.loads(text)["seed"])
    except (ValueError, KeyError, TypeError):
        return None


def read_episodes(recording: Recording) -> list[RecordedEpisode]:
    """The episodes in a recording, in order (a new scenario description starts one). A world
    summary counts for the episode whose seed it names (a recorder joining mid-run gets the
    latched summary of the episode before too)."""
    store = recording.typestore()
    wanted = [t for t, info in recording.topics.items()
              if info.msgtype in (SCENARIO_TYPE, WORLD_STATE_TYPE)
              or (info.msgtype == ACTION_BATCH_TYPE and t.endswith(APPLIED_SUFFIX))
              or (info.msgtype == STRING_TYPE and t.endswith(SUMMARY_SUFFIX))]
    episodes: list[RecordedEpisode] = []
    for message in recording.messages(wanted):
        msg = store.deserialize_cdr(message.data, message.msgtype)
        if message.msgtype == SCENARIO_TYPE:
            if not episodes or episodes[-1].scenario is not None:
                episodes.append(RecordedEpisode())
            episodes[-1].scenario = Scenario.from_json(msg.scenario_json)
            episodes[-1].policies = msg.policies
            continue
        if not episodes:
            episodes.append(RecordedEpisode())
        episode = episodes[-1]
        if message.msgtype == WORLD_STATE_TYPE:
            episode.states[int(msg.step)] = RecordedState.from_message(msg)
        elif message.msgtype == STRING_TYPE:
            episode.finished |= episode.scenario is not None and _summary_seed(msg.data) == episode.scenario.seed
        else:
            wire = np.asarray(msg.actions, dtype=np.int64)
            episode.actions[int(msg.step)] = np.stack([np.asarray(msg.agent_ids, dtype=np.int64),
                                                       np.where(wire == NO_ACTION_WIRE, NO_ACTION, wire)])
    return episodes


def resimulate(episode: RecordedEpisode) -> Iterator[World]:
    """The world at its start and after every step whose actions were recorded (the same
    object, advanced in place), until the first step with no recorded actions."""
    if episode.scenario is None:
        raise ValueError("the recording has no scenario description (/formic/scenario)")
    world = World(episode.scenario)
    yield world
    n = episode.scenario.config.n_agents
    while world.t in episode.actions and not world.done:
        ids, values = episode.actions[world.t]
        actions = np.full(n, NO_ACTION, dtype=np.int64)
        actions[ids] = values
        world.step(actions)
        yield world


def difference_from(world: World, state: RecordedState) -> str | None:
    """The first field where a recorded state differs from the re-simulated world."""
    if state.digest != world.state_digest():
        return f"state_digest recorded {state.digest}, re-simulated {world.state_digest()}"
    if state.score != world.score:
        return f"score recorded {state.score!r}, re-simulated {world.score!r}"
    if not (np.array_equal(state.rows, world.pos[:, 0]) and np.array_equal(state.cols, world.pos[:, 1])):
        return "agent positions differ"
    return None


def _described_episodes(path: str | os.PathLike, otherwise: str) -> list[RecordedEpisode]:
    episodes = [e for e in read_episodes(Recording(path)) if e.scenario is not None]
    if not episodes:
        raise ValueError(f"{path}: no scenario description recorded; {otherwise}")
    return episodes


def render_recording(path: str | os.PathLike, out: str | os.PathLike, scale: int = 4, fps: float = 20) -> int:
    """Rebuild the world states of a recording by re-simulation and write them as a GIF or
    MP4 (or the last state as a PNG). Returns the number of frames."""
    from formic_world.render import render_frame, render_frames_to_file, save_png

    episodes = _described_episodes(path, "nothing to render")
    frames = (render_frame(world, scale=scale, caption=True) for e in episodes for world in resimulate(e))
    out = Path(out)
    if out.suffix.lower() == ".png":
        save_png(deque(frames, maxlen=1)[0], out)
        return 1
    return render_frames_to_file(frames, out, fps=fps)


def view_recording(path: str | os.PathLike, view, rate: float = 1.0, dt: float = 0.1) -> int:
    """Re-simulate the recording into a live view (:class:`formic_view.LiveView`), paced at
    ``rate`` times sim time (``dt`` s a step; ``rate`` 0: as fast as possible). Returns the
    number of steps shown."""
    steps = 0
    for episode in _described_episodes(path, "nothing to show"):
        start = time.monotonic()
        for world in resimulate(episode):
            if rate > 0:
                time.sleep(max(0.0, start + world.t * dt / rate - time.monotonic()))
            view.publish(world, final=world.done or world.t not in episode.actions)
            steps += int(world.t > 0)
    return steps
