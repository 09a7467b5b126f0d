"""NumPy arrays <-> message array fields, fast, and the compact observation encoding.

Array fields are filled from ``array.array`` (about 1 µs a field; a NumPy array or a list
costs about 80 µs) and read back with ``np.frombuffer`` (no copy). Observations travel
float32 or compact (lossless, see :func:`encode_compact`); readers take either
(:func:`decode_observations`).
"""

from __future__ import annotations

import array
import math

import numpy as np
from formic_interfaces.msg import ObservationBatch


# ----------------------------------------------------------------------------- arrays
def typed(typecode: str, values: np.ndarray, dtype) -> array.array:
    out = array.array(typecode)
    out.frombytes(memoryview(np.ascontiguousarray(values, dtype=dtype)).cast("B"))
    return out


def f32(values: np.ndarray) -> array.array:
    return typed("f", values, np.float32)


def i32(values: np.ndarray) -> array.array:
    return typed("i", values, np.int32)


def u32(values: np.ndarray) -> array.array:
    return typed("I", values, np.uint32)


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


def observation_fields(observations: np.ndarray, encoding: str) -> dict:
    code = encoding_code(encoding)
    if code == ObservationBatch.ENCODING_FLOAT32:
        return dict(encoding=code, data=f32(observations))
    nonzero_bits, one_bits, other_values = encode_compact(observations)
    return dict(encoding=code, nonzero_bits=nonzero_bits, one_bits=one_bits, other_values=other_values)
