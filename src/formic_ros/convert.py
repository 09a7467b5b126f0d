"""NumPy arrays <-> formic_interfaces messages, fast.

Array fields are filled from ``array.array`` (about 1 µs a field; a NumPy array or a list
costs about 80 µs) and read back with ``np.frombuffer`` (no copy).

Observations travel float32 or compact (lossless, see :func:`encode_compact`); readers take
either (:func:`decode_observations`).
"""

from __future__ import annotations

import array
import math

import numpy as np
from builtin_interfaces.msg import Time
from formic_interfaces.msg import (
    ActionBatch,
    AgentObservation,
    ObservationBatch,
    ScenarioDescription,
    WorldState,
)
from geometry_msgs.msg import Point
from nav_msgs.msg import OccupancyGrid
from rosgraph_msgs.msg import Clock
from std_msgs.msg import ColorRGBA
from visualization_msgs.msg import Marker, MarkerArray

from formic_agent.policy import AgentBatch
from formic_world import Scenario, World
from formic_world.geometry import CACHE, N_ACTIONS, RESOURCE

from .qos import NO_ACTION_WIRE

SCENARIO_FORMAT_VERSION = 1
ACTION_COUNT = N_ACTIONS  # the learning host reads it


# ----------------------------------------------------------------------------- arrays
def _typed(typecode: str, values: np.ndarray, dtype) -> array.array:
    out = array.array(typecode)
    out.frombytes(memoryview(np.ascontiguousarray(values, dtype=dtype)).cast("B"))
    return out


def f32(values: np.ndarray) -> array.array:
    return _typed("f", values, np.float32)


def i32(values: np.ndarray) -> array.array:
    return _typed("i", values, np.int32)


def u32(values: np.ndarray) -> array.array:
    return _typed("I", values, np.uint32)


def u8(values: np.ndarray) -> bytes:
    return np.ascontiguousarray(values, dtype=np.uint8).tobytes()


def read(field, dtype) -> np.ndarray:
    """A received array field as a read-only NumPy view."""
    return np.frombuffer(field, dtype=dtype)


# ---------------------------------------------------------------- observation encoding
ENCODINGS = {"float32": ObservationBatch.ENCODING_FLOAT32, "compact": ObservationBatch.ENCODING_COMPACT}
_ONE = np.float32(1.0).view(np.uint32)  # the bits of 1.0


def encoding_code(name: str) -> int:
    try:
        return ENCODINGS[name]
    except KeyError:
        raise ValueError(f"unknown observation encoding {name!r}; choose from {', '.join(ENCODINGS)}") from None


def encode_compact(observations: np.ndarray) -> tuple[bytes, bytes, array.array]:
    """Rows of float32 observations, losslessly and small: per row, one bit per value that is
    not +0.0 (``nonzero_bits``); over all rows, one bit per such value that is exactly 1.0
    (``one_bits``); the remaining values as float32 (``other_values``). Observation channels
    are 0/1 but for the pheromone and the resource-entry fractions, so 128 agents' 0.5 MB
    become some 50 KB. Compared bitwise: every float (-0.0, NaN) comes back as it was."""
    rows, size = observations.shape[0], math.prod(observations.shape[1:])
    words = np.ascontiguousarray(observations, dtype=np.float32).view(np.uint32).reshape(rows, size)
    nonzero = words != 0
    kept = words[nonzero]
    is_one = kept == _ONE
    return u8(np.packbits(nonzero, axis=1)), u8(np.packbits(is_one)), f32(kept[~is_one].view(np.float32))


def decode_compact(nonzero_bits, one_bits, other_values, shape: tuple[int, ...]) -> np.ndarray:
    """Inverse of :func:`encode_compact`: float32 rows of ``shape`` (rows first), bit for bit."""
    rows, size = shape[0], math.prod(shape[1:])
    row_bytes = (size + 7) // 8
    nonzero_bits, one_bits = read(nonzero_bits, np.uint8), read(one_bits, np.uint8)
    others = read(other_values, np.uint32)
    if len(nonzero_bits) != rows * row_bytes:
        raise ValueError(f"compact observations: {len(nonzero_bits)} nonzero bytes for {rows} rows of {size} values")
    nonzero = np.unpackbits(nonzero_bits.reshape(rows, row_bytes), axis=1, count=size).view(bool)
    kept = np.full(np.count_nonzero(nonzero), _ONE, dtype=np.uint32)
    if len(one_bits) != (len(kept) + 7) // 8:
        raise ValueError(f"compact observations: {len(one_bits)} one-bit bytes for {len(kept)} nonzero values")
    is_other = ~np.unpackbits(one_bits, count=len(kept)).view(bool)
    if np.count_nonzero(is_other) != len(others):
        raise ValueError(f"compact observations: {len(others)} other values, {np.count_nonzero(is_other)} expected")
    kept[is_other] = others
    words = np.zeros((rows, size), dtype=np.uint32)
    words[nonzero] = kept
    return words.view(np.float32).reshape(shape)


def decode_observations(msg: ObservationBatch) -> np.ndarray:
    """The observations a received ObservationBatch carries, in either encoding, as float32
    (N, channels, size, size) (read-only when they came as float32)."""
    shape = (len(msg.agent_ids), msg.channels, msg.size, msg.size)
    if msg.encoding == ObservationBatch.ENCODING_FLOAT32:
        return read(msg.data, np.float32).reshape(shape)
    if msg.encoding == ObservationBatch.ENCODING_COMPACT:
        return decode_compact(msg.nonzero_bits, msg.one_bits, msg.other_values, shape)
    raise ValueError(f"unknown observation encoding {msg.encoding}")


def _observation_fields(observations: np.ndarray, encoding: str) -> dict:
    code = encoding_code(encoding)
    if code == ObservationBatch.ENCODING_FLOAT32:
        return dict(encoding=code, data=f32(observations))
    nonzero_bits, one_bits, other_values = encode_compact(observations)
    return dict(encoding=code, nonzero_bits=nonzero_bits, one_bits=one_bits, other_values=other_values)


# ------------------------------------------------------------------------ observations
def observation_batch(
    step: int,
    observations: np.ndarray,
    action_mask: np.ndarray,
    loads: np.ndarray,
    rewards: np.ndarray,
    queued: np.ndarray,
    positions: np.ndarray,
    world_shape: tuple[int, int],
    done: bool,
    agent_ids: np.ndarray | None = None,
    train_masks: np.ndarray | None = None,
    encoding: str = "compact",
) -> ObservationBatch:
    """The observations of ``agent_ids`` (default: every agent) as one message in ``encoding``
    (``float32`` or ``compact``); the arrays are indexed by agent id."""
    if agent_ids is None:
        agent_ids = np.arange(observations.shape[0])
    else:
        observations, action_mask, loads, rewards, queued, positions = (
            a[agent_ids] for a in (observations, action_mask, loads, rewards, queued, positions))
        train_masks = None if train_masks is None else train_masks[agent_ids]
    channels, size = observations.shape[1], observations.shape[2]
    return ObservationBatch(
        step=step,
        agent_ids=u32(agent_ids),
        channels=channels,
        size=size,
        **_observation_fields(observations, encoding),
        action_masks=u8(action_mask),
        loads=f32(loads),
        rewards=f32(rewards),
        queued=u8(queued),
        done=done,
        rows=i32(positions[:, 0]),
        cols=i32(positions[:, 1]),
        world_height=world_shape[0],
        world_width=world_shape[1],
        train_masks=u8(train_masks) if train_masks is not None else b"",
    )


def agent_observations(
    step: int,
    agent_ids: np.ndarray,
    observations: np.ndarray,
    action_mask: np.ndarray,
    loads: np.ndarray,
    rewards: np.ndarray,
    queued: np.ndarray,
    positions: np.ndarray,
    world_shape: tuple[int, int],
    done: bool,
) -> list[AgentObservation]:
    """One AgentObservation per agent in ``agent_ids`` (arrays indexed by agent id)."""
    channels, size = observations.shape[1], observations.shape[2]
    block = channels * size * size * 4
    raw = memoryview(np.ascontiguousarray(observations, dtype=np.float32)).cast("B")
    masks = np.ascontiguousarray(action_mask, dtype=np.uint8)
    out = []
    for a in agent_ids:
        a = int(a)
        data = array.array("f")
        data.frombytes(raw[a * block:(a + 1) * block])
        out.append(AgentObservation(
            step=step, agent_id=a, channels=channels, size=size, data=data,
            action_mask=masks[a].tobytes(), load=float(loads[a]), reward=float(rewards[a]),
            queued=bool(queued[a]), done=done, row=int(positions[a, 0]), col=int(positions[a, 1]),
            world_height=world_shape[0], world_width=world_shape[1],
        ))
    return out


def batch_from_observation_batch(msg: ObservationBatch, rows: np.ndarray | None = None) -> AgentBatch:
    """The rows ``rows`` of a received ObservationBatch (all rows when None) as an AgentBatch."""
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


def batch_from_agent_observations(msgs: list[AgentObservation]) -> AgentBatch:
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
def action_batch(step: int, agent_ids: np.ndarray, actions: np.ndarray) -> ActionBatch:
    """Actions 0-4 (or 255 for none) for ``agent_ids``."""
    return ActionBatch(step=step, agent_ids=u32(agent_ids), actions=u8(actions))


def applied_actions(step: int, actions: np.ndarray) -> ActionBatch:
    """What the world applied at ``step`` for every agent; NO_ACTION (-1) goes out as 255."""
    wire = np.where(actions < 0, NO_ACTION_WIRE, actions)
    return action_batch(step, np.arange(len(actions)), wire)


def actions_from_applied(msg: ActionBatch, n_agents: int) -> np.ndarray:
    """Inverse of :func:`applied_actions`: (N,) int64 with -1 where none arrived."""
    actions = np.full(n_agents, -1, dtype=np.int64)
    wire = read(msg.actions, np.uint8).astype(np.int64)
    actions[read(msg.agent_ids, np.uint32).astype(np.int64)] = np.where(wire == NO_ACTION_WIRE, -1, wire)
    return actions


# ------------------------------------------------------------------------------- state
def world_state(world: World, missed: np.ndarray) -> WorldState:
    """The full world as one message (for recorders, the planner's check and viewers)."""
    full = world.load_full
    remaining = np.where(world.resource_remaining < 0, -1.0, world.resource_remaining / full)
    height, width = world.grid.shape
    return WorldState(
        step=world.t,
        height=height,
        width=width,
        score=world.score,
        grid=u8(world.grid),
        pheromone=f32(world.visible_pheromone()),
        agent_rows=i32(world.pos[:, 0]),
        agent_cols=i32(world.pos[:, 1]),
        agent_loads=f32(world.loads),
        agent_queues=i32(world.queue_of),
        resource_rows=i32(world.resource_pos[:, 0]),
        resource_cols=i32(world.resource_pos[:, 1]),
        resource_directions=u8(world.resource_dir),
        resource_remaining=f32(remaining),
        missed_actions=u32(missed),
        state_digest=world.state_digest(),
    )


def scenario_description(scenario: Scenario, policies: str) -> ScenarioDescription:
    return ScenarioDescription(
        format_version=SCENARIO_FORMAT_VERSION,
        seed=int(scenario.seed),
        config_digest=scenario.config.digest(),
        scenario_json=scenario.to_json(),
        policies=policies,
    )


def scenario_from_description(msg: ScenarioDescription) -> Scenario:
    if msg.format_version != SCENARIO_FORMAT_VERSION:
        raise ValueError(f"scenario description format {msg.format_version}, expected {SCENARIO_FORMAT_VERSION}")
    return Scenario.from_json(msg.scenario_json)


# ----------------------------------------------------------------------------- viewers
def sim_time(step: int, dt: float) -> Time:
    nanos = int(round(step * dt * 1e9))
    return Time(sec=nanos // 1_000_000_000, nanosec=nanos % 1_000_000_000)


def clock(step: int, dt: float) -> Clock:
    return Clock(clock=sim_time(step, dt))


def occupancy_grid(world: World, stamp: Time, frame: str = "map") -> OccupancyGrid:
    """Grid and pheromone as an OccupancyGrid: free cells 0-60 by pheromone, resources 80,
    caches 90, obstacles 100. Map y grows northwards (row 0 is the top row), 1 m a cell."""
    height, width = world.grid.shape
    values = np.rint(np.clip(world.visible_pheromone(), 0.0, 1.0) * 60).astype(np.int8)
    values[world.grid == 1] = 100
    values[world.grid == RESOURCE] = 80
    values[world.grid == CACHE] = 90
    msg = OccupancyGrid()
    msg.header.stamp = stamp
    msg.header.frame_id = frame
    msg.info.map_load_time = stamp
    msg.info.resolution = 1.0
    msg.info.width = width
    msg.info.height = height
    msg.data = _typed("b", values[::-1], np.int8)
    return msg


def _colour(r: float, g: float, b: float) -> ColorRGBA:
    return ColorRGBA(r=r, g=g, b=b, a=1.0)


def agent_markers(world: World, stamp: Time, frame: str = "map") -> MarkerArray:
    """Agents (orange when carrying, blue when empty) and resources (green) as cube lists."""
    height = world.grid.shape[0]
    empty, loaded, food = _colour(0.2, 0.4, 1.0), _colour(1.0, 0.55, 0.0), _colour(0.1, 0.8, 0.2)

    def cubes(marker_id: int, ns: str, cells: np.ndarray, colours: list[ColorRGBA]) -> Marker:
        m = Marker(ns=ns, id=marker_id, type=Marker.CUBE_LIST, action=Marker.ADD)
        m.header.stamp = stamp
        m.header.frame_id = frame
        m.pose.orientation.w = 1.0
        m.scale.x = m.scale.y = m.scale.z = 0.9
        m.points = [Point(x=float(c) + 0.5, y=float(height - 1 - r) + 0.5, z=0.5) for r, c in cells]
        m.colors = colours
        return m

    carrying = world.carrying
    return MarkerArray(markers=[
        cubes(0, "agents", world.pos, [loaded if c else empty for c in carrying]),
        cubes(1, "resources", world.resource_pos, [food] * len(world.resource_pos)),
    ])
