"""Topic names and QoS profiles of the ForMIC ROS system (one place, documented in docs/ros.md).

Names are relative to the namespace (default ``/formic``) except ``/clock``. Everything is
reliable: lockstep cannot afford lost messages, and a resend would cost a deadline.
"""

from __future__ import annotations

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

NO_ACTION_WIRE = 255  # an applied action that did not arrive in time (ActionBatch.actions)

# Latched: late joiners (a restarted host, a recorder, a viewer) get the last message.
LATCHED = QoSProfile(
    history=HistoryPolicy.KEEP_LAST,
    depth=1,
    reliability=ReliabilityPolicy.RELIABLE,
    durability=DurabilityPolicy.TRANSIENT_LOCAL,
)
# The lockstep exchange: observations and actions (at most a step or two in flight).
STREAM = QoSProfile(
    history=HistoryPolicy.KEEP_LAST,
    depth=10,
    reliability=ReliabilityPolicy.RELIABLE,
    durability=DurabilityPolicy.VOLATILE,
)
# What the world logs each step (state, applied actions, clock, score): a deep writer history,
# so a subscriber that falls behind for a while (a recorder starting up) loses nothing.
LOG_DEPTH = 200
LOG = QoSProfile(
    history=HistoryPolicy.KEEP_LAST,
    depth=LOG_DEPTH,
    reliability=ReliabilityPolicy.RELIABLE,
    durability=DurabilityPolicy.VOLATILE,
)
# Viewer topics (map, markers): the newest one matters, and a viewer that opens late sees it.
VIEWER = LATCHED


def agent_node_name(agent_id: int) -> str:
    """The node name of agent K (``agent_K``); its topics are ``<namespace>/agent_K/...``."""
    return f"agent_{agent_id}"


def agent_topic(agent_id: int, leaf: str) -> str:
    """``agent_K/observation`` or ``agent_K/action``, relative to the namespace."""
    return f"{agent_node_name(agent_id)}/{leaf}"


def full_name(namespace: str, topic: str) -> str:
    """Absolute topic name (for messages and docs)."""
    return topic if topic.startswith("/") else f"{namespace.rstrip('/')}/{topic}"
