"""Every topic of the ForMIC ROS system: its name, message type and QoS (:data:`TOPICS`; one
place, documented in docs/ros.md).

Names are relative to the namespace (default ``/formic``) except ``/clock``; per-agent topics
are ``agent_K/observation`` and ``agent_K/action`` (:func:`agent_topic`). Everything is
reliable: lockstep cannot afford lost messages, and a resend would cost a deadline.
"""

from __future__ import annotations

from dataclasses import dataclass

from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy

DEFAULT_NAMESPACE = "/formic"

SCENARIO = "scenario"
OBSERVATIONS = "observations"
ACTIONS = "actions"
STATE = "state"
APPLIED_ACTIONS = "applied_actions"
SUMMARY = "summary"
MAP = "map"
AGENT_MARKERS = "agent_markers"
SCORE = "score"
CLOCK = "/clock"
AGENT_OBSERVATION = "observation"  # under the agent node: /formic/agent_K/observation
AGENT_ACTION = "action"  # /formic/agent_K/action
ROLLOUTS = "rollouts"  # learning hosts -> trainer
WEIGHTS = "weights"  # trainer -> learning hosts
CLAIMS = "claims"  # driver nodes -> world: the agents each drives (formic_ros.ownership)
OWNERS = "owners"  # world -> driver nodes: who drives which agent
RECORDER_MATCHES = "recorder_matches"  # recorders -> world and drivers: what each recorder's readers matched

NO_ACTION_WIRE = 255  # an applied action that did not arrive in time (ActionBatch.actions)


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
# Rollouts: a few chunks may wait while the trainer updates.
ROLLOUT_DEPTH = 16
ROLLOUT = reliable(ROLLOUT_DEPTH)


@dataclass(frozen=True)
class Topic:
    msgtype: str  # pkg/msg/Name
    qos: QoSProfile  # what the publisher offers

    @property
    def latched(self) -> bool:
        return self.qos.durability == DurabilityPolicy.TRANSIENT_LOCAL


_FORMIC = "formic_interfaces/msg/"
TOPICS: dict[str, Topic] = {
    SCENARIO: Topic(_FORMIC + "ScenarioDescription", LATCHED),
    SUMMARY: Topic("std_msgs/msg/String", LATCHED),
    STATE: Topic(_FORMIC + "WorldState", LOG),
    APPLIED_ACTIONS: Topic(_FORMIC + "ActionBatch", LOG),
    OBSERVATIONS: Topic(_FORMIC + "ObservationBatch", STREAM_WRITER),
    ACTIONS: Topic(_FORMIC + "ActionBatch", STREAM_WRITER),
    SCORE: Topic("std_msgs/msg/Float64", LOG),
    MAP: Topic("nav_msgs/msg/OccupancyGrid", VIEWER),
    AGENT_MARKERS: Topic("visualization_msgs/msg/MarkerArray", VIEWER),
    CLOCK: Topic("rosgraph_msgs/msg/Clock", LOG),
    AGENT_OBSERVATION: Topic(_FORMIC + "AgentObservation", STREAM_WRITER),  # under agent_K/
    AGENT_ACTION: Topic(_FORMIC + "AgentAction", STREAM_WRITER),  # under agent_K/
    ROLLOUTS: Topic(_FORMIC + "Rollout", ROLLOUT),
    WEIGHTS: Topic(_FORMIC + "Weights", LATCHED),
    CLAIMS: Topic("std_msgs/msg/String", LATCHED),
    OWNERS: Topic("std_msgs/msg/String", LATCHED),
    RECORDER_MATCHES: Topic("std_msgs/msg/String", LATCHED),
}
# The world's topics, which a recorder subscribes to at once (the rest it discovers).
WORLD_TOPICS = (SCENARIO, SUMMARY, STATE, APPLIED_ACTIONS, OBSERVATIONS, ACTIONS, SCORE, MAP, AGENT_MARKERS, CLOCK)


def agent_node_name(agent_id: int) -> str:
    """The node name of agent K (``agent_K``); its topics are ``<namespace>/agent_K/...``."""
    return f"agent_{agent_id}"


def agent_topic(agent_id: int, leaf: str) -> str:
    """``agent_K/observation`` or ``agent_K/action``, relative to the namespace."""
    return f"{agent_node_name(agent_id)}/{leaf}"


def full_name(namespace: str, topic: str) -> str:
    """Absolute topic name (for messages and docs)."""
    return topic if topic.startswith("/") else f"{namespace.rstrip('/')}/{topic}"
