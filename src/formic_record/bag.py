"""Recordings on disk: rosbag2 directories with MCAP storage, written, read and repaired
without rclpy, so the files are exactly what ROS-free tools (Foxglove, ``mcap``,
``mcap-ros2-support``, ``rosbags``) read.

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
import shutil
import sys
import time
from collections.abc import Iterable, Iterator, Mapping
from dataclasses import dataclass, field
from functools import partial
from importlib.metadata import PackageNotFoundError, version
from pathlib import Path
from typing import Any

from mcap.reader import make_reader
from mcap.records import Channel, Message, Metadata, Schema
from mcap.stream_reader import StreamReader
from mcap.writer import CompressionType
from mcap.writer import Writer as McapWriter
from rosbags.interfaces import Connection, MessageDefinitionFormat, Qos
from rosbags.rosbag2 import StoragePlugin
from rosbags.rosbag2 import Writer as RosbagWriter
from rosbags.rosbag2.metadata import parse_qos
from rosbags.typesys import Stores, get_types_from_msg, get_typestore
from ruamel.yaml import YAML

RUN_INFO_RECORD = "formic"  # MCAP metadata record with the run description
ROSBAG2_RECORD = "rosbag2"  # the record rosbag2 writes at close (its serialized metadata)
DEFAULT_CHUNK_BYTES = 256 * 1024
DEFAULT_FLUSH_SECONDS = 0.5
KEPT_SUFFIX = ".truncated"  # what --repair keeps of the file it replaced
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
        self._mcap = McapWriter(self._file, chunk_size=chunk_bytes, compression=CompressionType.ZSTD)
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
            self.flush()

    def flush(self) -> None:
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


class BagWriter:
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

    def __enter__(self) -> "BagWriter":
        return self

    def __exit__(self, *exc) -> None:
        self.close()


# ----------------------------------------------------------------------------- reading
@dataclass(frozen=True)
class RecordedMessage:
    topic: str
    msgtype: str
    log_time: int  # nanoseconds
    data: bytes  # CDR, as published


@dataclass
class TopicInfo:
    msgtype: str
    count: int
    qos: list[Qos] = field(default_factory=list)


class RecordingError(RuntimeError):
    """A recording that cannot be read at all."""


def find_mcap(path: str | os.PathLike) -> Path:
    """The MCAP file of a recording directory (or the file itself)."""
    path = Path(path)
    if path.is_file():
        return path
    meta = path / "metadata.yaml"
    if meta.is_file():
        info = YAML(typ="safe").load(meta.read_text())["rosbag2_bagfile_information"]
        return path / info["relative_file_paths"][0]
    files = sorted(path.glob("*.mcap"))
    if len(files) != 1:
        raise RecordingError(f"{path}: expected one .mcap file in the recording, found {len(files)}")
    return files[0]


class Recording:
    """A recording opened for reading: indexed when the file is complete, else by a streaming
    read of the chunks that reached the disk (``streamed`` is then true, ``problem`` says why)."""

    def __init__(self, path: str | os.PathLike):
        self.path = Path(path)
        self.mcap_path = find_mcap(self.path)
        self.metadata_path = self.path / "metadata.yaml" if self.path.is_dir() else None
        self.streamed = False
        self.problem: str | None = None
        self.schemas: dict[str, str] = {}  # type name -> definition text
        self.topics: dict[str, TopicInfo] = {}
        self.run_info: dict[str, str] = {}
        self.stream_error: str | None = None
        try:
            self._scan_indexed()
        except Exception:  # noqa: BLE001 - any failure of the index means: stream it
            self.streamed = True
            self.problem = "no usable summary (the writer did not close the file)"
            self._scan_streaming()
        if self.metadata_path is not None and self.metadata_path.is_file():
            info = YAML(typ="safe").load(self.metadata_path.read_text())["rosbag2_bagfile_information"]
            self.run_info = {**self.run_info, **(info.get("custom_data") or {})}
        elif self.metadata_path is not None:
            self.problem = (self.problem + "; " if self.problem else "") + "no metadata.yaml"

    @property
    def cut_short(self) -> bool:
        """The writer did not close the file: its last messages may be lost."""
        return self.streamed or REPAIRED_KEY in self.run_info

    @property
    def complete(self) -> bool:
        return not self.streamed and self.problem is None

    @property
    def message_count(self) -> int:
        return sum(t.count for t in self.topics.values())

    def _scan_indexed(self) -> None:
        with self.mcap_path.open("rb") as handle:
            reader = make_reader(handle)
            summary = reader.get_summary()
            if summary is None or summary.statistics is None:
                raise RecordingError("the file has no summary section")
            schemas = summary.schemas
            counts = summary.statistics.channel_message_counts
            for schema in schemas.values():
                self.schemas[schema.name] = schema.data.decode()
            for channel in summary.channels.values():
                self._add_channel(channel, schemas[channel.schema_id], counts.get(channel.id, 0))
            for record in reader.iter_metadata():
                if record.name == RUN_INFO_RECORD:
                    self.run_info.update(record.metadata)

    def _add_channel(self, channel: Channel, schema: Schema, count: int) -> None:
        qos = parse_qos(channel.metadata.get("offered_qos_profiles", ""))
        self.topics[channel.topic] = TopicInfo(schema.name, count, qos)

    def _stream_records(self) -> Iterator[Any]:
        """Every record a streaming read reaches; stops quietly where the file was cut."""
        with self.mcap_path.open("rb") as handle:
            records = StreamReader(handle).records
            while True:
                try:
                    record = next(records)
                except StopIteration:
                    return
                except Exception as exc:  # noqa: BLE001 - a truncated record ends the readable part
                    self.stream_error = f"{exc.__class__.__name__} at byte {handle.tell()}"
                    return
                yield record

    def _scan_streaming(self) -> None:
        schemas: dict[int, Schema] = {}
        channels: dict[int, Channel] = {}
        counts: dict[int, int] = {}
        for record in self._stream_records():
            if isinstance(record, Message):
                counts[record.channel_id] = counts.get(record.channel_id, 0) + 1
            elif isinstance(record, Schema):
                schemas[record.id] = record
                self.schemas[record.name] = record.data.decode()
            elif isinstance(record, Channel):
                channels[record.id] = record
            elif isinstance(record, Metadata) and record.name == RUN_INFO_RECORD:
                self.run_info.update(record.metadata)
        for channel in channels.values():
            self._add_channel(channel, schemas[channel.schema_id], counts.get(channel.id, 0))
        if self.stream_error:
            self.problem += f"; the streaming read stopped where the file was cut ({self.stream_error})"

    def messages(self, topics: Iterable[str] | None = None) -> Iterator[RecordedMessage]:
        """Messages in log-time order (file order when streamed), optionally of some topics."""
        wanted = None if topics is None else set(topics)
        if not self.streamed:
            with self.mcap_path.open("rb") as handle:
                for schema, channel, message in make_reader(handle).iter_messages(
                    topics=None if wanted is None else sorted(wanted), log_time_order=True
                ):
                    yield RecordedMessage(channel.topic, schema.name, message.log_time, message.data)
            return
        channels: dict[int, tuple[str, str]] = {}
        schema_names: dict[int, str] = {}
        for record in self._stream_records():
            if isinstance(record, Schema):
                schema_names[record.id] = record.name
            elif isinstance(record, Channel):
                channels[record.id] = (record.topic, schema_names.get(record.schema_id, ""))
            elif isinstance(record, Message):
                topic, msgtype = channels[record.channel_id]
                if wanted is None or topic in wanted:
                    yield RecordedMessage(topic, msgtype, record.log_time, record.data)

    def typestore(self):
        return typestore_from_schemas(self.schemas)

    def describe(self) -> str:
        how = "streaming read (file cut short)" if self.streamed else "indexed read"
        text = f"{self.mcap_path}: {self.message_count} messages on {len(self.topics)} topics, {how}"
        return text + (f"; {self.problem}" if self.problem else "")


# ----------------------------------------------------------------------------- repair
@dataclass
class RepairReport:
    repaired: bool
    messages: int
    kept: Path | None  # the original file, kept beside the repaired one
    note: str


def repair_recording(path: str | os.PathLike) -> RepairReport:
    """Rebuild the MCAP summary and ``metadata.yaml`` of a recording cut short (like
    ``ros2 bag reindex``): every message a streaming read recovers is rewritten into a complete
    file beside the original, which then takes the original's name atomically; the original
    stays as ``<name>.mcap.truncated``."""
    path = Path(path)
    if not path.is_dir():
        raise RecordingError(f"{path}: --repair works on a recording directory")
    recording = Recording(path)
    if recording.complete:
        return RepairReport(False, recording.message_count, None, "recording is complete; nothing to repair")
    original = recording.mcap_path
    kept = original.with_name(original.name + KEPT_SUFFIX)
    if kept.exists():
        raise RecordingError(f"{kept} exists (an earlier repair kept it); move it away first")
    work = path / ".formic-repair"
    shutil.rmtree(work, ignore_errors=True)
    work.mkdir()
    staged = work / path.name
    count = 0
    with BagWriter(staged, typestore=recording.typestore(), file_name=original.name) as writer:
        for topic, info in recording.topics.items():
            writer.add_topic(topic, info.msgtype, info.qos)
        for message in recording.messages():
            writer.write(message.topic, message.log_time, message.data)
            count += 1
        writer.set_run_info({**recording.run_info, REPAIRED_KEY: original.name + KEPT_SUFFIX})
    try:
        os.link(original, kept)
    except OSError:
        shutil.copy2(original, kept)
    os.replace(staged / original.name, original)
    os.replace(staged / "metadata.yaml", path / "metadata.yaml")
    shutil.rmtree(work)
    note = f"rewrote {count} messages with a full index; the original is kept as {kept.name}"
    return RepairReport(True, count, kept, note)
