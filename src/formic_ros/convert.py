"""One codec: every formic_interfaces message the nodes exchange, as encode/decode pairs.

Observations are :class:`formic_agent.policy.AgentBatch` rows (batched or one message per
agent), actions int64 arrays (NO_ACTION -1 travels as 255). The learning messages (rollouts
and weights) are in :mod:`formic_ros.convert_learning`, array fields and the compact observation
encoding in :mod:`formic_ros.wire`, viewer messages (one way) in :mod:`formic_ros.world.viewer_msgs`. :func:`checked_subscription` is how a
node takes messages from others: bytes that do not decode are reported, not dropped unseen.
"""

from __future__ import annotations

import array
import functools
import struct
from typing import TYPE_CHECKING

import numpy as np
from rclpy.serialization import deserialize_message, serialize_message
from formic_interfaces.msg import ActionBatch, AgentAction, AgentObservation, ObservationBatch, ScenarioDescription, WorldState

from formic_agent.policy import AgentBatch
from formic_topics import NO_ACTION_WIRE, SCENARIO_FORMAT_VERSION
from formic_world.geometry import N_ACTIONS
from formic_world.scenario import Scenario

if TYPE_CHECKING:
    from formic_world.world import World

from .wire import decode_observations, f32, i32, observation_fields, read, u8, u32


def checked_subscription(node, msg_type, topic: str, profile, on_message, on_malformed):
    """A subscription that hands ``on_message`` decoded messages and ``on_malformed(topic,
    size)`` the samples whose CDR bytes do not decode (rclpy itself drops those with only a
    C-level log line: a malformed or truncated message would go uncounted)."""

    def take(data: bytes) -> None:
        try:
            msg = deserialize_message(data, msg_type)
        except RuntimeError:
            on_malformed(topic, len(data))
            return
        on_message(msg)

    return node.create_subscription(msg_type, topic, take, profile, raw=True)


# ------------------------------------------------------------------------ observations
def _rows(batch: AgentBatch, rewards: np.ndarray, rows) -> tuple[np.ndarray, ...]:
    """The batch's arrays and ``rewards`` (indexed like the batch), restricted to ``rows``."""
    arrays = (batch.agent_ids, batch.observations, batch.action_mask, batch.positions, batch.loads,
              batch.queued, rewards)
    return arrays if rows is None else tuple(a[rows] for a in arrays)


def encode_observation_batch(batch: AgentBatch, rewards: np.ndarray, done: bool, rows=None,
                             train_masks: np.ndarray | None = None, encoding: str = "compact") -> ObservationBatch:
    """Rows ``rows`` (default: all) of a batch, with their rewards and training masks (indexed
    like the batch), as one message in ``encoding`` (``float32`` or ``compact``)."""
    ids, observations, action_mask, positions, loads, queued, rewards = _rows(batch, rewards, rows)
    if rows is not None and train_masks is not None:
        train_masks = train_masks[rows]
    return ObservationBatch(
        step=batch.step, agent_ids=u32(ids), channels=observations.shape[1], size=observations.shape[2],
        **observation_fields(observations, encoding),
        action_masks=u8(action_mask), loads=f32(loads), rewards=f32(rewards), queued=u8(queued), done=done,
        rows=i32(positions[:, 0]), cols=i32(positions[:, 1]),
        world_height=batch.world_shape[0], world_width=batch.world_shape[1],
        train_masks=u8(train_masks) if train_masks is not None else b"",
    )


def decode_observation_batch(msg: ObservationBatch, rows: np.ndarray | None = None) -> AgentBatch:
    """The rows ``rows`` of a received ObservationBatch (all rows when None) as an AgentBatch
    (its rewards, done and training masks: :func:`read` ``msg.rewards``, ...)."""
    ids = read(msg.agent_ids, np.uint32).astype(np.int64)
    rows = slice(None) if rows is None else rows
    n = len(ids)
    return AgentBatch(
        step=msg.step,
        agent_ids=ids[rows],
        observations=decode_observations(msg)[rows],
        action_mask=read(msg.action_masks, np.uint8).reshape(n, N_ACTIONS)[rows].astype(bool),
        positions=np.stack([read(msg.rows, np.int32), read(msg.cols, np.int32)], axis=1)[rows].astype(np.int64),
        loads=read(msg.loads, np.float32)[rows].astype(np.float64),
        queued=read(msg.queued, np.uint8)[rows].astype(bool),
        world_shape=(msg.world_height, msg.world_width),
    )


def rows_of(msg: ObservationBatch, agent_ids: np.ndarray) -> np.ndarray:
    """The row of each of ``agent_ids`` in a received ObservationBatch (-1 where absent)."""
    ids = read(msg.agent_ids, np.uint32).astype(np.int64)
    lookup = np.full(max(int(ids.max(initial=-1)), int(agent_ids.max())) + 1, -1, dtype=np.int64)
    lookup[ids] = np.arange(len(ids))
    return lookup[agent_ids]


def encode_agent_observations(batch: AgentBatch, rewards: np.ndarray, done: bool, rows=None) -> list[AgentObservation]:
    """One AgentObservation per row in ``rows`` (default: all) of a batch."""
    ids, observations, action_mask, positions, loads, queued, rewards = _rows(batch, rewards, rows)
    channels, size = observations.shape[1], observations.shape[2]
    block = channels * size * size * 4
    raw = memoryview(np.ascontiguousarray(observations, dtype=np.float32)).cast("B")
    masks = np.ascontiguousarray(action_mask, dtype=np.uint8)
    out = []
    for i, a in enumerate(ids):
        data = array.array("f")
        data.frombytes(raw[i * block:(i + 1) * block])
        out.append(AgentObservation(
            step=batch.step, agent_id=int(a), channels=channels, size=size, data=data,
            action_mask=masks[i].tobytes(), load=float(loads[i]), reward=float(rewards[i]),
            queued=bool(queued[i]), done=done, row=int(positions[i, 0]), col=int(positions[i, 1]),
            world_height=batch.world_shape[0], world_width=batch.world_shape[1],
        ))
    return out


CDR_LE = b"\x00\x01\x00\x00"  # a serialized message's encapsulation header: plain CDR, little-endian


@functools.cache
def _agent_observation_layout(values: int) -> np.dtype:
    """AgentObservation's CDR bytes (little-endian, after the header) for ``values`` floats of
    data and a 5-entry action mask, as one NumPy record: fields at their aligned offsets."""
    tail = 16 + 4 * values  # 4 bytes before the action mask's length (the record is tail + 40 = 56 + 4 * values)
    return np.dtype({
        "names": ["header", "step", "agent_id", "channels", "size", "data_len", "data", "mask_len", "mask",
                  "load", "reward", "queued", "done", "row", "col", "height", "width"],
        "formats": ["V4", "<u4", "<u4", "<u2", "<u2", "<u4", ("<f4", values), "<u4", ("u1", N_ACTIONS),
                    "<f4", "<f4", "u1", "u1", "<i4", "<i4", "<u2", "<u2"],
        "offsets": [0, 4, 8, 12, 14, 16, 20, tail + 4, tail + 8,
                    tail + 16, tail + 20, tail + 24, tail + 25, tail + 28, tail + 32, tail + 36, tail + 38],
        "itemsize": tail + 40,
    })


def agent_observation_bytes(batch: AgentBatch, rewards: np.ndarray, done: bool, rows=None) -> list[bytes]:
    """:func:`encode_agent_observations` as serialized messages, built for all rows at once
    (a publisher sends bytes as they are: no message objects, no per-message conversion)."""
    ids, observations, action_mask, positions, loads, queued, rewards = _rows(batch, rewards, rows)
    channels, size = observations.shape[1], observations.shape[2]
    records = np.zeros(len(ids), dtype=_agent_observation_layout(channels * size * size))
    records["header"] = np.void(CDR_LE)
    records["step"], records["agent_id"] = batch.step, ids
    records["channels"], records["size"], records["data_len"] = channels, size, channels * size * size
    records["data"] = observations.reshape(len(ids), -1)
    records["mask_len"], records["mask"] = N_ACTIONS, action_mask
    records["load"], records["reward"], records["queued"], records["done"] = loads, rewards, queued, done
    records["row"], records["col"] = positions[:, 0], positions[:, 1]
    records["height"], records["width"] = batch.world_shape
    data, width = memoryview(records.view(np.uint8)), records.dtype.itemsize
    return [data[i:i + width].tobytes() for i in range(0, len(data), width)]  # one copy each, none of the whole


def agent_observation_head(data: bytes) -> tuple[bytes, int, int, bool] | None:
    """A serialized AgentObservation in the layout of :func:`agent_observation_bytes` (bytes in
    another layout, say big-endian, are serialized again by rclpy), with its step, agent id and
    done flag; None when it does not decode or its action mask is not 5 entries."""
    if data[:2] != CDR_LE[:2] or len(data) < 20 or len(data) != 56 + 4 * int.from_bytes(data[16:20], "little"):
        try:
            msg = deserialize_message(data, AgentObservation)
        except RuntimeError:
            return None
        data = serialize_message(msg)  # little-endian here
        if len(msg.action_mask) != N_ACTIONS or data[:2] != CDR_LE[:2]:
            return None
    mask_len = 20 + 4 * int.from_bytes(data[16:20], "little")  # where the action mask's length is
    if int.from_bytes(data[mask_len:mask_len + 4], "little") != N_ACTIONS:
        return None
    step, agent_id = struct.unpack_from("<II", data, 4)
    return data, step, agent_id, bool(data[mask_len + 21])


def decode_agent_observation_bytes(datas: list[bytes]) -> AgentBatch:
    """Several agents' serialized AgentObservations of one step (as :func:`agent_observation_head`
    returns them) as an AgentBatch, decoded as one array."""
    records = np.frombuffer(b"".join(datas), dtype=_agent_observation_layout(int.from_bytes(datas[0][16:20], "little")))
    channels, size = int(records["channels"][0]), int(records["size"][0])
    return AgentBatch(
        step=int(records["step"][0]),
        agent_ids=records["agent_id"].astype(np.int64),
        observations=np.array(records["data"]).reshape(len(records), channels, size, size),  # a copy: writable
        action_mask=records["mask"].astype(bool),
        positions=np.stack([records["row"], records["col"]], axis=1).astype(np.int64),
        loads=records["load"].astype(np.float64),
        queued=records["queued"].astype(bool),
        world_shape=(int(records["height"][0]), int(records["width"][0])),
    )


def decode_agent_observations(msgs: list[AgentObservation]) -> AgentBatch:
    """Several agents' AgentObservation messages of one step as an AgentBatch."""
    first = msgs[0]
    shape = (first.channels, first.size, first.size)
    return AgentBatch(
        step=first.step,
        agent_ids=np.array([m.agent_id for m in msgs], dtype=np.int64),
        observations=np.stack([read(m.data, np.float32).reshape(shape) for m in msgs]),
        action_mask=np.stack([read(m.action_mask, np.uint8) for m in msgs]).astype(bool),
        positions=np.array([(m.row, m.col) for m in msgs], dtype=np.int64).reshape(len(msgs), 2),
        loads=np.array([m.load for m in msgs], dtype=np.float64),
        queued=np.array([m.queued for m in msgs], dtype=bool),
        world_shape=(first.world_height, first.world_width),
    )


# ----------------------------------------------------------------------------- actions
def encode_actions(step: int, agent_ids: np.ndarray, actions: np.ndarray) -> ActionBatch:
    """Actions 0-4 of ``agent_ids``; NO_ACTION (-1) goes out as 255."""
    actions = np.asarray(actions)
    return ActionBatch(step=step, agent_ids=u32(agent_ids), actions=u8(np.where(actions < 0, NO_ACTION_WIRE, actions)))


def decode_actions(msg: ActionBatch) -> tuple[int, np.ndarray, np.ndarray]:
    """Inverse of :func:`encode_actions`: step, agent ids and actions (int64, -1 for 255)."""
    wire = read(msg.actions, np.uint8).astype(np.int64)
    return msg.step, read(msg.agent_ids, np.uint32).astype(np.int64), np.where(wire == NO_ACTION_WIRE, -1, wire)


AGENT_ACTION = struct.Struct("<4sIIB3x")  # AgentAction's CDR bytes: header, step, agent id, action, padding
CDR_LE_KIND = int.from_bytes(CDR_LE[:2], "little")  # the header's first two bytes, as read by AGENT_ACTIONS


def agent_action_bytes(step: int, agent_id: int, action: int) -> bytes:
    """An AgentAction, serialized (what a publisher sends as it is)."""
    return AGENT_ACTION.pack(CDR_LE, step, agent_id, action)


def decode_agent_action(data: bytes) -> tuple[int, int, int] | None:
    """A serialized AgentAction's step, agent id and action (None: the bytes do not decode).
    Little-endian CDR is read directly (one per agent and step); anything else goes through rclpy."""
    if len(data) >= 13 and data[:2] == CDR_LE[:2]:
        return AGENT_ACTION.unpack_from(data.ljust(AGENT_ACTION.size, b"\0"))[1:]
    try:
        msg = deserialize_message(data, AgentAction)
    except RuntimeError:
        return None
    return msg.step, msg.agent_id, msg.action


AGENT_ACTIONS = np.dtype([("kind", "<u2"), ("options", "<u2"), ("step", "<u4"), ("agent_id", "<u4"),
                          ("action", "u1"), ("padding", "V3")])  # AGENT_ACTION as a NumPy record


def decode_agent_actions(datas: list[bytes]) -> np.ndarray | None:
    """Many serialized AgentActions as one record array (``AGENT_ACTIONS``: step, agent_id,
    action), a step's worth at once; None unless every one is little-endian CDR of 13-16
    bytes (then :func:`decode_agent_action` reads each)."""
    if not all(13 <= len(data) <= AGENT_ACTION.size for data in datas):
        return None
    records = np.frombuffer(b"".join(data.ljust(AGENT_ACTION.size, b"\0") for data in datas), dtype=AGENT_ACTIONS)
    return records if (records["kind"] == CDR_LE_KIND).all() else None


def encode_applied(step: int, actions: np.ndarray) -> ActionBatch:
    """What the world applied at ``step``, every agent's (NO_ACTION where none arrived)."""
    return encode_actions(step, np.arange(len(actions)), actions)


def decode_applied(msg: ActionBatch, n_agents: int) -> np.ndarray:
    """Inverse of :func:`encode_applied`: (N,) int64 with -1 where none arrived."""
    _, ids, values = decode_actions(msg)
    actions = np.full(n_agents, -1, dtype=np.int64)
    actions[ids] = values
    return actions


# ------------------------------------------------------------------------------- state
def encode_state(world: World, missed: np.ndarray) -> WorldState:
    """The full world as one message (for recorders, the planner's check and viewers; read
    back by :class:`formic_record.replay.RecordedState`)."""
    full = world.load_full
    remaining = np.where(world.resource_remaining < 0, -1.0, world.resource_remaining / full)
    height, width = world.grid.shape
    return WorldState(
        step=world.t, height=height, width=width, score=world.score,
        grid=u8(world.grid), pheromone=f32(world.visible_pheromone()),
        agent_rows=i32(world.pos[:, 0]), agent_cols=i32(world.pos[:, 1]),
        agent_loads=f32(world.loads), agent_queues=i32(world.queue_of),
        resource_rows=i32(world.resource_pos[:, 0]), resource_cols=i32(world.resource_pos[:, 1]),
        resource_directions=u8(world.resource_dir), resource_remaining=f32(remaining),
        missed_actions=u32(missed), state_digest=world.state_digest(),
    )


# ---------------------------------------------------------------------------- scenario
def encode_scenario(scenario: Scenario, policies: str) -> ScenarioDescription:
    return ScenarioDescription(
        format_version=SCENARIO_FORMAT_VERSION,
        seed=int(scenario.seed),
        config_digest=scenario.config.digest(),
        scenario_json=scenario.to_json(),
        policies=policies,
    )


def decode_scenario(msg: ScenarioDescription) -> Scenario:
    if msg.format_version != SCENARIO_FORMAT_VERSION:
        raise ValueError(f"scenario description format {msg.format_version}, expected {SCENARIO_FORMAT_VERSION}")
    return Scenario.from_json(msg.scenario_json)
