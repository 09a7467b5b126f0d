"""The compact observation encoding, without ROS: the world's wire (formic_ros.wire) encodes and
decodes with it, and recording verification decodes what a bag holds with the same code.

Per row, one bit per value that is not +0.0 (``nonzero_bits``); over all rows, one bit per such
value that is exactly 1.0 (``one_bits``); the remaining values as float32 (``other_values``).
Observation channels are 0/1 but for the pheromone and the resource-entry fractions, so 128
agents' 0.5 MB become some 50 KB. Lossless bit for bit: -0.0 and NaN come back as they were.
"""

from __future__ import annotations

import math

import numpy as np

_ONE = np.float32(1.0).view(np.uint32)  # the bits of 1.0


def encode_compact(observations: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Rows of float32 observations as (nonzero_bits uint8, one_bits uint8, other_values float32)."""
    rows, size = observations.shape[0], math.prod(observations.shape[1:])
    words = np.ascontiguousarray(observations, dtype=np.float32).view(np.uint32).reshape(rows, size)
    nonzero = words != 0
    kept = words[nonzero]
    is_one = kept == _ONE
    return np.packbits(nonzero, axis=1).ravel(), np.packbits(is_one), kept[~is_one].view(np.float32)


def _values(field, dtype) -> np.ndarray:
    """A message field as ``dtype`` values: bytes or array.array from rclpy (no copy), a NumPy
    array from a bag reader."""
    if isinstance(field, np.ndarray):
        return np.ascontiguousarray(field, dtype=dtype)
    return np.frombuffer(field, dtype=dtype)


def decode_compact(nonzero_bits, one_bits, other_values, shape: tuple[int, ...]) -> np.ndarray:
    """Inverse of :func:`encode_compact`: float32 rows of ``shape`` (rows first), bit for bit.
    ValueError when the fields' lengths do not fit together."""
    rows, size = shape[0], math.prod(shape[1:])
    row_bytes = (size + 7) // 8
    nonzero_bits, one_bits = _values(nonzero_bits, np.uint8), _values(one_bits, np.uint8)
    others = _values(other_values, np.float32).view(np.uint32)
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
