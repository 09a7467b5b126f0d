"""What the re-simulated world would have published, compared field by field with every
recorded message the world publishes (no rclpy: the recorded CDR is decoded with the
recording's own schemas, the expected values come from :class:`formic_world.World`).

Each check returns None or the first differing field (``field: recorded ..., expected ...``).
Bitwise wherever the world publishes bits (observations, pheromone, loads, rewards).
"""

from __future__ import annotations

import numpy as np

from formic_record.compact import decode_compact
from formic_topics import ENCODING_COMPACT, ENCODING_FLOAT32
from formic_world import World
from formic_world.metric_frame import MetricFrame, occupancy_values


def stamp_ns(stamp) -> int:
    return int(stamp.sec) * 1_000_000_000 + int(stamp.nanosec)


def sim_time_ns(step: int, dt: float) -> int:
    """As :func:`formic_ros.world.viewer_msgs.sim_time` stamps step ``step``."""
    return int(round(step * dt * 1e9))


def _bits(values, dtype) -> bytes:
    return np.ascontiguousarray(np.asarray(values), dtype=dtype).tobytes()


def _field(name: str, recorded, expected, dtype) -> str | None:
    """Compare an array (or scalar) field as the bytes of ``dtype``."""
    got, want = _bits(recorded, dtype), _bits(expected, dtype)
    if got == want:
        return None
    r, e = np.frombuffer(got, dtype=dtype), np.frombuffer(want, dtype=dtype)
    if r.shape != e.shape:
        return f"{name}: recorded {r.size} values, expected {e.size}"
    unsigned = np.dtype(f"u{r.itemsize}")
    where = int(np.flatnonzero(r.view(unsigned) != e.view(unsigned))[0])
    return f"{name}[{where}]: recorded {r[where]!r}, expected {e[where]!r}"


def _fields(fields) -> str | None:
    """The first of ``(name, recorded, expected, dtype)`` fields that differs."""
    return next(filter(None, (_field(*f) for f in fields)), None)


def _scalars(pairs) -> str | None:
    problem = _fields((name, [recorded], [expected], dtype) for name, recorded, expected, dtype in pairs)
    return problem and problem.replace("[0]", "")


def check_agent_observation(msg, world: World) -> str | None:
    result, a = world.last_result, int(msg.agent_id)
    if not 0 <= a < len(world.pos):
        return f"agent_id: recorded {a}, the world has {len(world.pos)} agents"
    height, width = world.grid.shape
    obs = result.observations[a]
    return _scalars([
        ("step", msg.step, world.t, np.uint32), ("channels", msg.channels, obs.shape[0], np.uint16),
        ("size", msg.size, obs.shape[1], np.uint16),
        ("load", msg.load, world.loads[a], np.float32), ("reward", msg.reward, result.rewards[a], np.float32),
        ("queued", msg.queued, world.queued[a], np.bool_), ("done", msg.done, result.done, np.bool_),
        ("row", msg.row, world.pos[a, 0], np.int32), ("col", msg.col, world.pos[a, 1], np.int32),
        ("world_height", msg.world_height, height, np.uint16), ("world_width", msg.world_width, width, np.uint16),
    ]) or _field("data", msg.data, obs.ravel(), np.float32) or \
        _field("action_mask", msg.action_mask, result.action_mask[a], np.uint8)


def check_observation_batch(msg, world: World) -> str | None:
    result = world.last_result
    ids = np.asarray(msg.agent_ids, dtype=np.int64)
    if len(ids) and (ids.min() < 0 or ids.max() >= len(world.pos)):
        return f"agent_ids: {ids.tolist()} outside the world's {len(world.pos)} agents"
    height, width = world.grid.shape
    obs = result.observations[ids]
    problem = _scalars([
        ("step", msg.step, world.t, np.uint32), ("channels", msg.channels, obs.shape[1], np.uint16),
        ("size", msg.size, obs.shape[2], np.uint16), ("done", msg.done, result.done, np.bool_),
        ("world_height", msg.world_height, height, np.uint16), ("world_width", msg.world_width, width, np.uint16),
    ])
    if problem:
        return problem
    shape = (len(ids), int(msg.channels), int(msg.size), int(msg.size))
    try:
        if msg.encoding == ENCODING_FLOAT32:
            got = np.ascontiguousarray(msg.data, dtype=np.float32).reshape(shape)
        elif msg.encoding == ENCODING_COMPACT:
            got = decode_compact(msg.nonzero_bits, msg.one_bits, msg.other_values, shape)
        else:
            return f"encoding: unknown value {msg.encoding}"
    except ValueError as exc:
        return f"observations: {exc}"
    fields = [("observations", got, obs, np.float32),
              ("action_masks", msg.action_masks, result.action_mask[ids], np.uint8),
              ("loads", msg.loads, world.loads[ids], np.float32),
              ("rewards", msg.rewards, result.rewards[ids], np.float32),
              ("queued", msg.queued, world.queued[ids], np.uint8),
              ("rows", msg.rows, world.pos[ids, 0], np.int32), ("cols", msg.cols, world.pos[ids, 1], np.int32)]
    if len(msg.train_masks):
        fields.append(("train_masks", msg.train_masks, world.training_action_mask(result.action_mask)[ids], np.uint8))
    return _fields(fields)


def check_state(msg, world: World) -> str | None:
    height, width = world.grid.shape
    digest = world.state_digest()
    if msg.state_digest != digest:
        return f"state_digest: recorded {msg.state_digest}, re-simulated {digest}"
    remaining = np.where(world.resource_remaining < 0, -1.0, world.resource_remaining / world.load_full)
    fields = [
        ("grid", msg.grid, world.grid, np.uint8), ("pheromone", msg.pheromone, world.visible_pheromone(), np.float32),
        ("agent_rows", msg.agent_rows, world.pos[:, 0], np.int32),
        ("agent_cols", msg.agent_cols, world.pos[:, 1], np.int32),
        ("agent_loads", msg.agent_loads, world.loads, np.float32),
        ("agent_queues", msg.agent_queues, world.queue_of, np.int32),
        ("resource_rows", msg.resource_rows, world.resource_pos[:, 0], np.int32),
        ("resource_cols", msg.resource_cols, world.resource_pos[:, 1], np.int32),
        ("resource_directions", msg.resource_directions, world.resource_dir, np.uint8),
        ("resource_remaining", msg.resource_remaining, remaining, np.float32),
    ]
    scalars = [("step", msg.step, world.t, np.uint32), ("height", msg.height, height, np.uint16),
               ("width", msg.width, width, np.uint16), ("score", msg.score, world.score, np.float64)]
    # the resource fields are not filled by every publisher (older recordings)
    problem = _scalars(scalars) or _fields(f for f in fields if len(f[1]) or not f[0].startswith("resource"))
    return problem and problem.replace("expected", "re-simulated")


def check_clock(msg, step: int, dt: float) -> str | None:
    got, want = stamp_ns(msg.clock), sim_time_ns(step, dt)
    return None if got == want else f"clock: recorded {got} ns, expected {want} ns (step {step}, dt {dt})"


def map_frame(msg, world: World) -> MetricFrame | None:
    """The metric frame a recorded map declares (its resolution and origin), or None if unusable."""
    try:
        return MetricFrame(*world.grid.shape, float(msg.info.resolution), float(msg.info.origin.position.x),
                           float(msg.info.origin.position.y))
    except ValueError:
        return None


def check_map(msg, world: World) -> str | None:
    height, width = world.grid.shape
    if map_frame(msg, world) is None:
        return f"info.resolution: {msg.info.resolution} is no cell size"
    return _scalars([("info.width", msg.info.width, width, np.uint32),
                     ("info.height", msg.info.height, height, np.uint32)]) or \
        _field("data", msg.data, occupancy_values(world), np.int8)


def check_markers(msg, world: World, frame: MetricFrame | None = None) -> str | None:
    """Markers at their cells' centres in ``frame`` (the same step's map's; 1 m cells from the
    origin when the step has no map)."""
    frame = frame or MetricFrame(*world.grid.shape)
    expected = {"agents": world.pos, "resources": world.resource_pos}
    for marker in msg.markers:
        cells = expected.get(marker.ns)
        if cells is None:
            continue
        got = np.array([(p.x, p.y) for p in marker.points], dtype=np.float64).reshape(-1, 2)
        want = np.array([frame.cell_centre(int(r), int(c)) for r, c in cells], dtype=np.float64).reshape(-1, 2)
        problem = _field(f"markers[{marker.ns}].points", got, want.reshape(-1, 2), np.float64)
        if problem:
            return problem
    return None
