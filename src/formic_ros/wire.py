"""NumPy arrays <-> message array fields, fast, and the compact observation encoding.

Array fields are filled from ``array.array`` (about 1 µs a field; a NumPy array or a list
costs about 80 µs) and read back with ``np.frombuffer`` (no copy). Observations travel
float32 or compact (lossless, see :mod:`formic_record.compact`), in ObservationBatch and in
Rollout alike (the same ``encoding`` and compact fields); readers take either
(:func:`decode_observations`, :func:`decode_encoded`).
"""

from __future__ import annotations

import array

import numpy as np
from formic_interfaces.msg import ObservationBatch

from formic_record.compact import decode_compact, encode_compact
from formic_topics import ENCODING_COMPACT, ENCODING_FLOAT32


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
ENCODINGS = {"float32": ENCODING_FLOAT32, "compact": ENCODING_COMPACT}


def encoding_code(name: str) -> int:
    try:
        return ENCODINGS[name]
    except KeyError:
        raise ValueError(f"unknown observation encoding {name!r}; choose from {', '.join(ENCODINGS)}") from None


def decode_observations(msg: ObservationBatch) -> np.ndarray:
    """The observations a received ObservationBatch carries, in either encoding, as float32
    (N, channels, size, size) (read-only when they came as float32)."""
    return decode_encoded(msg, msg.data, (len(msg.agent_ids), msg.channels, msg.size, msg.size))


def decode_encoded(msg, data, shape: tuple[int, ...]) -> np.ndarray:
    """float32 observations of ``shape`` (rows first) from a message with the encoding's fields
    (``encoding``, ``nonzero_bits``, ``one_bits``, ``other_values``; float32 ones in ``data``).
    ValueError when they do not fit ``shape`` or the encoding is unknown."""
    if msg.encoding == ENCODING_FLOAT32:
        values = read(data, np.float32)
        if values.size != int(np.prod(shape)):
            raise ValueError(f"{values.size} float32 observation values, expected {int(np.prod(shape))} {shape}")
        return values.reshape(shape)
    if msg.encoding == ENCODING_COMPACT:
        return decode_compact(msg.nonzero_bits, msg.one_bits, msg.other_values, shape)
    raise ValueError(f"unknown observation encoding {msg.encoding}")


def observation_fields(observations: np.ndarray, encoding: str, data_field: str = "data") -> dict:
    """A message's encoding fields for ``observations`` (rows first), the float32 values under
    ``data_field`` (ObservationBatch: ``data``, Rollout: ``observations``)."""
    code = encoding_code(encoding)
    if code == ENCODING_FLOAT32:
        return {"encoding": code, data_field: f32(observations)}
    nonzero_bits, one_bits, other_values = encode_compact(observations)
    return dict(encoding=code, nonzero_bits=u8(nonzero_bits), one_bits=u8(one_bits), other_values=f32(other_values))
