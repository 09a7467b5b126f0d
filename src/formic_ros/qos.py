"""Every topic's QoS profile (:data:`TOPICS` pairs it with the topic's name and message type
from :mod:`formic_topics`; one place, documented in docs/ros.md).

Everything is reliable: lockstep cannot afford lost messages, and a resend would cost a deadline.
"""

from __future__ import annotations

from dataclasses import dataclass

from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy

import formic_topics as topics


def reliable(depth: int, latched: bool = False) -> QoSProfile:
    """Keep-last ``depth``, reliable; transient-local when ``latched``, else volatile."""
    durability = DurabilityPolicy.TRANSIENT_LOCAL if latched else DurabilityPolicy.VOLATILE
    return QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=depth, reliability=ReliabilityPolicy.RELIABLE,
                      durability=durability)


# Latched: late joiners (a restarted host, a recorder, a viewer) get the last message.
LATCHED = reliable(1, latched=True)
# The lockstep exchange: observations and actions (at most a step or two in flight).
STREAM = reliable(10)
# What the writers of that exchange keep (the world's observations, a driver's actions). A
# keep-last writer drops its oldest sample when full even if a reliable reader has not
# acknowledged it, so the writer keeps more than any reader: a recorder that falls behind for a
# while still gets every message (measured with depth 10: on a loaded machine, at 340 lockstep
# steps/s, a recorder lost steps 1-9 of every agent's observations in about 1 run in 6).
STREAM_WRITER = reliable(100)
# An agent node's observation reader: only the newest waits, so a slow robot answers the
# latest step instead of working through a backlog (the world's writer keeps STREAM_WRITER's
# depth, so a recorder that falls behind still gets every observation).
LATEST = reliable(1)
# What the world logs each step (state, applied actions, clock, score): a deep writer history,
# so a subscriber that falls behind for a while (a recorder starting up) loses nothing.
LOG_DEPTH = 200
LOG = reliable(LOG_DEPTH)
# Viewer topics (map, markers): the newest one matters, and a viewer that opens late sees it.
VIEWER = LATCHED
# Rollouts: a few chunks may wait in a host's writer, and the trainer's reader keeps all that
# arrive while it updates (a keep-last reader would drop the oldest).
ROLLOUT_DEPTH = 16
ROLLOUT = reliable(ROLLOUT_DEPTH)
ROLLOUT_READER = QoSProfile(history=HistoryPolicy.KEEP_ALL, reliability=ReliabilityPolicy.RELIABLE)


@dataclass(frozen=True)
class Topic:
    msgtype: str  # pkg/msg/Name
    qos: QoSProfile  # what the publisher offers

    @property
    def latched(self) -> bool:
        return self.qos.durability == DurabilityPolicy.TRANSIENT_LOCAL


_OFFERED: dict[str, QoSProfile] = {  # by each topic's publishers
    topics.SCENARIO: LATCHED,
    topics.SUMMARY: LATCHED,
    topics.STATE: LOG,
    topics.APPLIED_ACTIONS: LOG,
    topics.OBSERVATIONS: STREAM_WRITER,
    topics.ACTIONS: STREAM_WRITER,
    topics.SCORE: LOG,
    topics.MAP: VIEWER,
    topics.AGENT_MARKERS: VIEWER,
    topics.CLOCK: LOG,
    topics.AGENT_OBSERVATION: STREAM_WRITER,  # under agent_K/
    topics.AGENT_ACTION: STREAM_WRITER,  # under agent_K/
    topics.ROLLOUTS: ROLLOUT,
    topics.WEIGHTS: LATCHED,
    topics.ROLLOUTS_TAKEN: LATCHED,
    topics.CLAIMS: LATCHED,
    topics.OWNERS: LATCHED,
    topics.RECORDER_MATCHES: LATCHED,
    topics.ROBOT_GOAL: STREAM_WRITER,  # under agent_K/
    topics.ROBOT_STATUS: STREAM_WRITER,  # under agent_K/
}
TOPICS: dict[str, Topic] = {name: Topic(msgtype, _OFFERED[name]) for name, msgtype in topics.TOPIC_TYPES.items()}
