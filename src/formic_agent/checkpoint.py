"""Checkpoints: written atomically, read with ``weights_only=True`` (never unpickle code).

A checkpoint is a plain dict of tensors and primitives: the network configuration travels
with the weights, so loading needs no guessing.
"""

from __future__ import annotations

import dataclasses
import hashlib
import io
import os
import pickle
import re
import warnings
from pathlib import Path
from typing import Any, BinaryIO

import torch

from formic_world.errors import InputError
from formic_world.files import atomic_open
from formic_world.limits import MAX_CHECKPOINT_BYTES

from .inputs import NetworkConfig

from .network import ForMICNet

CHECKPOINT_FORMAT = "formic-checkpoint"
CHECKPOINT_VERSION = 1
ZIP_MAGIC = b"PK\x03\x04"  # a zip archive's first local file header


class CheckpointError(InputError):
    """A model file that cannot be used, with the reason."""


def _payload(net: ForMICNet, **extra: Any) -> dict[str, Any]:
    return {"format": CHECKPOINT_FORMAT, "version": CHECKPOINT_VERSION, "network": net.config.to_dict(),
            "state_dict": net.state_dict(), **extra}


def save_checkpoint(path: str | os.PathLike, net: ForMICNet, **extra: Any) -> None:
    """``net`` and ``extra`` as a checkpoint at ``path`` (:func:`write_checkpoint`)."""
    write_checkpoint(path, _payload(net, **extra))


def write_checkpoint(path: str | os.PathLike, payload: dict[str, Any]) -> None:
    """Write to a temporary file and rename: a crash never leaves a half-written checkpoint."""
    with atomic_open(path, "wb") as handle:
        torch.save(payload, handle)


def read_checkpoint(source: str | os.PathLike | bytes) -> dict[str, Any]:
    """Load and validate a checkpoint (a path, or its bytes as sent over ROS)."""
    name = _name(source)
    try:
        handle = io.BytesIO(source) if isinstance(source, bytes) else open(source, "rb")
    except OSError as exc:
        raise CheckpointError(f"{name}: cannot read ({exc.strerror})") from exc
    with handle:
        _check_container(handle, name)
        try:
            with warnings.catch_warnings():  # torch warns of a pickle protocol it may not read, then fails
                warnings.filterwarnings("ignore", "Detected pickle protocol", UserWarning)
                payload = torch.load(handle, map_location="cpu", weights_only=True)
        except Exception as exc:  # torch raises many types for corrupt or unsafe files
            raise CheckpointError(f"{name}: not a readable ForMIC checkpoint ({_load_failure(exc)})") from exc
    if not isinstance(payload, dict) or payload.get("format") != CHECKPOINT_FORMAT:
        raise CheckpointError(f"{name}: not a ForMIC checkpoint")
    if payload.get("version") != CHECKPOINT_VERSION:
        raise CheckpointError(f"{name}: checkpoint version {payload.get('version')} is not supported")
    return payload


def _check_container(handle: BinaryIO, name: str) -> None:
    """Refuse, before torch reads a byte of it, a file over MAX_CHECKPOINT_BYTES and one that
    is not a zip archive (torch.save writes one): torch would parse a text file or a bare pickle
    as a legacy format and fail with a bare "KeyError: 101"."""
    size = handle.seek(0, os.SEEK_END)
    handle.seek(0)
    if size > MAX_CHECKPOINT_BYTES:
        raise CheckpointError(f"{name}: {size:,} bytes is over the limit of {MAX_CHECKPOINT_BYTES:,} for a model file")
    if size == 0:
        raise CheckpointError(f"{name}: not a ForMIC checkpoint (the file is empty)")
    if handle.read(len(ZIP_MAGIC)) != ZIP_MAGIC:
        raise CheckpointError(f"{name}: not a ForMIC checkpoint (torch.save writes a zip archive; this is "
                              "something else)")
    handle.seek(0)


def _name(source: str | os.PathLike | bytes) -> str:
    return "<bytes>" if isinstance(source, bytes) else str(source)


def _load_failure(exc: Exception) -> str:
    """One line on why torch could not load a file. torch's refusal of anything but tensors and
    plain data suggests ``weights_only=False``, which would run code from the file: never
    repeated."""
    if isinstance(exc, pickle.UnpicklingError) or "weights_only" in str(exc):
        return "not a torch file of tensors and plain data"
    if isinstance(exc, EOFError):
        return "the file is empty or cut short"
    first_sentence = re.split(r"(?<=[a-z0-9])\. (?=[A-Z])|\n", str(exc).strip())[0]
    return f"{exc.__class__.__name__}: {first_sentence}" if first_sentence else exc.__class__.__name__


def load_network(source: str | os.PathLike | bytes) -> tuple[ForMICNet, dict[str, Any]]:
    payload = read_checkpoint(source)
    if not isinstance(payload.get("network"), dict):
        raise CheckpointError(f"{_name(source)}: the checkpoint has no network configuration")
    try:  # before any layer is allocated: NetworkConfig refuses widths over the limits
        config = NetworkConfig.from_dict(payload["network"])
    except (ValueError, TypeError) as exc:
        raise CheckpointError(f"{_name(source)}: {exc}") from exc
    try:
        net = ForMICNet(config)
        net.load_state_dict(payload["state_dict"])
    except (KeyError, RuntimeError, ValueError, TypeError) as exc:
        raise CheckpointError(f"{_name(source)}: checkpoint does not match its network configuration "
                              f"({_load_failure(exc)})") from exc
    net.eval()
    return net, payload


def initialise_from(net: ForMICNet, source: ForMICNet) -> None:
    """Start ``net`` from ``source``'s weights (a warm start). The two may differ only in extra
    inputs ``net`` reads and ``source`` did not: their fc1 columns start at zero, so the
    widened network acts exactly as ``source`` did until it learns to use them."""
    same_body = dataclasses.replace(net.config, nest_input=False, action_input=False) == dataclasses.replace(
        source.config, nest_input=False, action_input=False)
    added = set(net.extra_columns()) - set(source.extra_columns())
    if not same_body or set(source.extra_columns()) - set(net.extra_columns()):
        raise CheckpointError(f"cannot start network {net.config} from {source.config}: only extra inputs may be added")
    state = source.state_dict()
    if added:
        weight = torch.zeros_like(net.fc1.weight)
        fc = net.config.fc
        weight[:, :fc] = state["fc1.weight"][:, :fc]
        target_column = {column: fc + i for i, column in enumerate(net.extra_columns())}
        for i, column in enumerate(source.extra_columns()):
            weight[:, target_column[column]] = state["fc1.weight"][:, fc + i]
        state["fc1.weight"] = weight
    net.load_state_dict(state)


def checkpoint_id(path: str | os.PathLike) -> str:
    """Short content hash that names a model in recordings and model cards."""
    return hashlib.sha256(Path(path).read_bytes()).hexdigest()[:12]


def state_dict_bytes(net: ForMICNet) -> bytes:
    """Weights as bytes for the ROS weights topic (loaded with weights_only=True)."""
    buffer = io.BytesIO()
    torch.save(_payload(net), buffer)
    return buffer.getvalue()
