"""ForMIC's topics without ROS: every topic's name and message type, and the values their
messages encode (sentinels, encodings, format versions). The nodes (:mod:`formic_ros`) publish
under these names and recordings (:mod:`formic_record`) are read by them; each topic's QoS
needs rclpy and is in :mod:`formic_ros.qos`. Documented in docs/ros.md and docs/interfaces.md.

Topic names are relative to the namespace (default ``/formic``) except ``/clock``; per-agent
topics are ``agent_K/observation`` and ``agent_K/action`` (:func:`agent_topic`).
"""

from __future__ import annotations

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
ROLLOUTS_TAKEN = "rollouts_taken"  # asynchronous actors' trainer -> their hosts: rollouts taken from each actor
CLAIMS = "claims"  # driver nodes -> world: the agents each drives (formic_ros.world.claims)
OWNERS = "owners"  # world -> driver nodes: who drives which agent
RECORDER_MATCHES = "recorder_matches"  # recorders -> world and drivers: what each recorder's readers matched
ROBOT_GOAL = "robot_goal"  # world -> robot bridge, under agent_K/: the cells a step takes robot agent K through
ROBOT_STATUS = "robot_status"  # robot bridge -> world, under agent_K/: arrived, failed, or its pose on the way

# Message types, as recordings name them (package/msg/Name).
SCENARIO_TYPE = "formic_interfaces/msg/ScenarioDescription"
OBSERVATION_BATCH_TYPE = "formic_interfaces/msg/ObservationBatch"
ACTION_BATCH_TYPE = "formic_interfaces/msg/ActionBatch"
AGENT_OBSERVATION_TYPE = "formic_interfaces/msg/AgentObservation"
AGENT_ACTION_TYPE = "formic_interfaces/msg/AgentAction"
WORLD_STATE_TYPE = "formic_interfaces/msg/WorldState"
ROLLOUT_TYPE = "formic_interfaces/msg/Rollout"
WEIGHTS_TYPE = "formic_interfaces/msg/Weights"
STRING_TYPE = "std_msgs/msg/String"
FLOAT64_TYPE = "std_msgs/msg/Float64"
OCCUPANCY_GRID_TYPE = "nav_msgs/msg/OccupancyGrid"
MARKER_ARRAY_TYPE = "visualization_msgs/msg/MarkerArray"
CLOCK_TYPE = "rosgraph_msgs/msg/Clock"
ROBOT_GOAL_TYPE = "formic_interfaces/msg/RobotGoal"
ROBOT_STATUS_TYPE = "formic_interfaces/msg/RobotStatus"

TOPIC_TYPES: dict[str, str] = {
    SCENARIO: SCENARIO_TYPE,
    SUMMARY: STRING_TYPE,
    STATE: WORLD_STATE_TYPE,
    APPLIED_ACTIONS: ACTION_BATCH_TYPE,
    OBSERVATIONS: OBSERVATION_BATCH_TYPE,
    ACTIONS: ACTION_BATCH_TYPE,
    SCORE: FLOAT64_TYPE,
    MAP: OCCUPANCY_GRID_TYPE,
    AGENT_MARKERS: MARKER_ARRAY_TYPE,
    CLOCK: CLOCK_TYPE,
    AGENT_OBSERVATION: AGENT_OBSERVATION_TYPE,  # under agent_K/
    AGENT_ACTION: AGENT_ACTION_TYPE,  # under agent_K/
    ROLLOUTS: ROLLOUT_TYPE,
    WEIGHTS: WEIGHTS_TYPE,
    ROLLOUTS_TAKEN: STRING_TYPE,
    CLAIMS: STRING_TYPE,
    OWNERS: STRING_TYPE,
    RECORDER_MATCHES: STRING_TYPE,
    ROBOT_GOAL: ROBOT_GOAL_TYPE,  # under agent_K/
    ROBOT_STATUS: ROBOT_STATUS_TYPE,  # under agent_K/
}
# The world's topics, which a recorder subscribes to at once (the rest it discovers).
WORLD_TOPICS = (SCENARIO, SUMMARY, STATE, APPLIED_ACTIONS, OBSERVATIONS, ACTIONS, SCORE, MAP, AGENT_MARKERS, CLOCK)

# Values messages carry.
NO_ACTION_WIRE = 255  # an action that did not arrive in time (ActionBatch.actions)
ENCODING_FLOAT32, ENCODING_COMPACT = 0, 1  # ObservationBatch.encoding, Rollout.encoding (their constants)
SCENARIO_FORMAT_VERSION = 1  # ScenarioDescription.format_version
EXTRA_INPUT_COUNT = 10  # Rollout.extra_inputs per agent and frame: formic_agent.network.N_EXTRA_INPUTS


def agent_node_name(agent_id: int) -> str:
    """The node name of agent K (``agent_K``); its topics are ``<namespace>/agent_K/...``."""
    return f"agent_{agent_id}"


def agent_topic(agent_id: int, leaf: str) -> str:
    """``agent_K/observation`` or ``agent_K/action``, relative to the namespace."""
    return f"{agent_node_name(agent_id)}/{leaf}"


def full_name(namespace: str, topic: str) -> str:
    """Absolute topic name (for messages and docs)."""
    return topic if topic.startswith("/") else f"{namespace.rstrip('/')}/{topic}"
