"""Recordings on disk: rosbag2 directories with MCAP storage, written here (read and repaired
by :mod:`formic_record.reading`) without rclpy, so the files are exactly what ROS-free tools
(Foxglove, ``mcap``, ``mcap-ros2-support``, ``rosbags``) read.

A recording is ``DIR/metadata.yaml`` beside ``DIR/DIR.mcap`` (profile ``ros2``, schema
encoding ``ros2msg``, message encoding ``cdr``), as ``ros2 bag record -s mcap`` writes it.
``rosbags``' writer produces the rosbag2 side (connections, type hashes, QoS, the metadata);
the MCAP file itself goes through ``mcap``'s writer so that chunks stay small and reach the
disk often: a writer killed mid-run loses at most its last chunk, and a streaming read
recovers the rest. What reproduces the run is in ``custom_data`` and, written as soon as it
is known, in an MCAP metadata record named ``formic``: a recording cut short still has it.
"""

from __future__ import annotations

import os
import sys
import time
from collections.abc import Iterable, Mapping
from contextlib import AbstractContextManager
from functools import partial
from importlib.metadata import PackageNotFoundError, version
from pathlib import Path
from typing import Any

from mcap.writer import CompressionType
from mcap.writer import Writer as McapWriter
from rosbags.interfaces import Connection, MessageDefinitionFormat, Qos
from rosbags.rosbag2 import StoragePlugin
from rosbags.rosbag2 import Writer as RosbagWriter
from rosbags.typesys import Stores, get_types_from_msg, get_typestore

RUN_INFO_RECORD = "formic"  # MCAP metadata record with the run description
ROSBAG2_RECORD = "rosbag2"  # the record rosbag2 writes at close (its serialized metadata)
DEFAULT_CHUNK_BYTES = 256 * 1024
DEFAULT_FLUSH_SECONDS = 0.5
REPAIRED_KEY = "repaired_from"  # custom_data of a repaired recording: its tail was lost
FORMIC_PACKAGE = "formic_interfaces"


def package_version() -> str:
    try:
        return version("formic-ros")
    except PackageNotFoundError:
        return "unknown"


# ----------------------------------------------------------------------------- types
def formic_msg_dir() -> Path:
    """The ``.msg`` files of formic_interfaces: the installed copy (what the compiled types
    were built from) when there is one, else the repository's sources."""
    installed = Path(sys.prefix) / "share" / FORMIC_PACKAGE / "msg"
    if installed.is_dir():
        return installed
    return Path(__file__).resolve().parents[2] / "ros2_ws" / FORMIC_PACKAGE / "msg"


def formic_typestore(msg_dir: Path | None = None):
    """rosbags' ROS 2 Jazzy typestore plus our own types, parsed from their ``.msg`` text."""
    store = get_typestore(Stores.ROS2_JAZZY)
    types: dict[str, Any] = {}
    for path in sorted((msg_dir or formic_msg_dir()).glob("*.msg")):
        types.update(get_types_from_msg(path.read_text(), f"{FORMIC_PACKAGE}/msg/{path.stem}"))
    store.register(types)
    return store


def typestore_from_schemas(schemas: Mapping[str, str]):
    """A typestore holding exactly the types a recording declares (its ``ros2msg`` schemas),
    so reading needs neither rclpy nor our sources."""
    store = get_typestore(Stores.EMPTY)
    for name, text in schemas.items():
        try:
            store.register(get_types_from_msg(text, name))
        except Exception:  # noqa: BLE001 - a schema we cannot parse leaves its topic opaque
            continue
    return store


# ----------------------------------------------------------------------------- writing
class _ChunkedMcapStorage:
    """rosbags' storage-writer protocol on ``mcap``'s writer: small zstd chunks, flushed to
    the disk at least every ``flush_seconds``, and extra metadata records."""

    def __init__(self, path: Path, _compression, *, file_name: str | None, chunk_bytes: int,
                 flush_seconds: float):
        self.path = path / (file_name or f"{path.name}.mcap")
        self._file = self.path.open("xb")
        self._mcap = McapWriter(self._file, chunk_size=chunk_bytes, compression=CompressionType.ZSTD,
                                 enable_data_crcs=True)  # DataEnd covers header and metadata too
        self._mcap.start(profile="ros2", library=f"formic-ros {package_version()} (rosbags, mcap)")
        self._schemas: dict[str, int] = {}
        self._channels: dict[int, int] = {}
        self._flush_seconds = flush_seconds
        self._last_flush = time.monotonic()

    def add_msgtype(self, connection: Connection) -> None:
        encoding = "ros2msg" if connection.msgdef.format == MessageDefinitionFormat.MSG else "ros2idl"
        self._schemas[connection.msgtype] = self._mcap.register_schema(
            connection.msgtype, encoding, connection.msgdef.data.encode()
        )

    def add_connection(self, connection: Connection, offered_qos_profiles: str) -> None:
        self._channels[connection.id] = self._mcap.register_channel(
            connection.topic, connection.ext.serialization_format, self._schemas[connection.msgtype],
            {"offered_qos_profiles": offered_qos_profiles},
        )

    def write(self, connection: Connection, timestamp: int, data: bytes | memoryview) -> None:
        self._mcap.add_message(self._channels[connection.id], log_time=timestamp, data=bytes(data),
                               publish_time=timestamp)
        self.flush_if_due()

    def flush_if_due(self) -> None:
        if time.monotonic() - self._last_flush >= self._flush_seconds:
            self._mcap.flush()  # ends the chunk in progress and flushes the file
            self._last_flush = time.monotonic()

    def add_metadata(self, name: str, data: Mapping[str, str]) -> None:
        self._mcap.add_metadata(name, dict(data))
        self._file.flush()

    def close(self, _version: int, metadata: str) -> None:
        self._mcap.add_metadata(ROSBAG2_RECORD, {"serialized_metadata": metadata})
        self._mcap.finish()
        self._file.close()

    def abort(self) -> None:
        self._file.close()


class BagWriter(AbstractContextManager):
    """A rosbag2 (MCAP) recording being written: topics are added as they are discovered and
    messages are written as the CDR bytes they arrived as."""

    def __init__(self, path: str | os.PathLike, typestore=None, chunk_bytes: int = DEFAULT_CHUNK_BYTES,
                 flush_seconds: float = DEFAULT_FLUSH_SECONDS, file_name: str | None = None):
        self.path = Path(path)
        self.typestore = typestore if typestore is not None else formic_typestore()
        self._writer = RosbagWriter(self.path, version=9, storage_plugin=StoragePlugin.MCAP)
        self._writer.STORAGE_PLUGINS = {StoragePlugin.MCAP: partial(
            _ChunkedMcapStorage, file_name=file_name, chunk_bytes=chunk_bytes, flush_seconds=flush_seconds,
        )}
        self._writer.open()
        self.mcap_path: Path = self._writer.storage.path
        self._connections: dict[str, Connection] = {}

    def knows_type(self, msgtype: str) -> bool:
        return msgtype in self.typestore.fielddefs

    def add_topic(self, topic: str, msgtype: str, qos: Iterable[Qos] = ()) -> None:
        self._connections[topic] = self._writer.add_connection(
            topic, msgtype, typestore=self.typestore, offered_qos_profiles=list(qos)
        )

    def write(self, topic: str, timestamp_ns: int, data: bytes | memoryview) -> None:
        self._writer.write(self._connections[topic], timestamp_ns, data)

    def set_run_info(self, info: Mapping[str, str]) -> None:
        """Store what reproduces the run: in ``custom_data`` (metadata.yaml, at close) and at
        once in a ``formic`` MCAP metadata record (survives a kill)."""
        for key, value in info.items():
            self._writer.set_custom_data(key, str(value))
        self._writer.storage.add_metadata(RUN_INFO_RECORD, {k: str(v) for k, v in info.items()})

    def flush_if_due(self) -> None:
        self._writer.storage.flush_if_due()

    def close(self) -> None:
        if self._writer.storage is not None:
            self._writer.close()

    def __exit__(self, *exc) -> None:
        self.close()
