"""Reading recordings (indexed, or streamed when the writer was cut short) and repairing
them (see :mod:`formic_record.bag` for the format)."""

from __future__ import annotations

import os
import shutil
from collections.abc import Iterable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from mcap.reader import make_reader
from mcap.records import Channel, Message, Metadata, Schema
from mcap.stream_reader import StreamReader
from rosbags.interfaces import Qos
from rosbags.rosbag2.metadata import parse_qos
from ruamel.yaml import YAML

from .bag import REPAIRED_KEY, RUN_INFO_RECORD, BagWriter, typestore_from_schemas
from .integrity import check_integrity, salvage

KEPT_SUFFIX = ".truncated"  # what --repair keeps of the file it replaced


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
        self._corruption: str | None | bool = False  # not checked yet
        if not self.mcap_path.is_file():
            raise RecordingError(f"{self.mcap_path}: no such file")
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

    def corruption(self) -> str | None:
        """None when every CRC of the file verifies, else what failed (one line; a full read)."""
        if self._corruption is False:
            self._corruption = check_integrity(self.mcap_path)
        return self._corruption

    def check(self) -> None:
        """Raise :class:`RecordingError` if the file is corrupted."""
        problem = self.corruption()
        if problem:
            raise RecordingError(problem + " (formic replay --repair keeps what verifies)")

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
                found = make_reader(handle, validate_crcs=True).iter_messages(
                    topics=None if wanted is None else sorted(wanted), log_time_order=True)
                while True:
                    try:
                        schema, channel, message = next(found)
                    except StopIteration:
                        return
                    except Exception as exc:  # noqa: BLE001 - a damaged chunk: a clean error
                        detail = " ".join(str(exc).split())[:160]
                        raise RecordingError(f"{self.mcap_path.name}: corrupted: {exc.__class__.__name__}: "
                                             f"{detail} (formic replay --repair keeps what verifies)") from None
                    yield RecordedMessage(channel.topic, schema.name, message.log_time, message.data)
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
    corrupted: bool = False  # CRCs failed (not merely cut short)
    dropped: int = 0  # messages lost to damaged chunks (when the summary still counted them)


def _salvaged_topics(records) -> tuple[dict[str, TopicInfo], dict[str, str], list[RecordedMessage], dict]:
    schemas: dict[int, Schema] = {}
    channels: dict[int, Channel] = {}
    messages, run_info = [], {}
    for record in records:
        if isinstance(record, Schema):
            schemas[record.id] = record
        elif isinstance(record, Channel):
            channels[record.id] = record
        elif isinstance(record, Metadata) and record.name == RUN_INFO_RECORD:
            run_info.update(record.metadata)
        elif isinstance(record, Message) and record.channel_id in channels:
            channel = channels[record.channel_id]
            schema = schemas.get(channel.schema_id)
            if schema is not None:
                messages.append(RecordedMessage(channel.topic, schema.name, record.log_time, record.data))
    topics = {}
    for channel in channels.values():
        if channel.schema_id in schemas:
            qos = parse_qos(channel.metadata.get("offered_qos_profiles", ""))
            topics[channel.topic] = TopicInfo(schemas[channel.schema_id].name, 0, qos)
    for message in messages:
        topics[message.topic].count += 1
    definitions = {s.name: s.data.decode() for s in schemas.values()}
    return topics, definitions, sorted(messages, key=lambda m: m.log_time), run_info


def repair_recording(path: str | os.PathLike) -> RepairReport:
    """Rebuild the MCAP summary and ``metadata.yaml`` of a recording cut short (like
    ``ros2 bag reindex``) or corrupted: every message a streaming read recovers from chunks
    whose CRC verifies is rewritten into a complete file beside the original, which then
    takes the original's name atomically; the original stays as ``<name>.mcap.truncated``."""
    path = Path(path)
    if not path.is_dir():
        raise RecordingError(f"{path}: --repair works on a recording directory")
    recording = Recording(path)
    corruption = recording.corruption()
    if recording.complete and not corruption:
        return RepairReport(False, recording.message_count, None, "recording is complete and every CRC "
                            "verifies; nothing to repair")
    original = recording.mcap_path
    kept = original.with_name(original.name + KEPT_SUFFIX)
    if kept.exists():
        raise RecordingError(f"{kept} exists (an earlier repair kept it); move it away first")
    rescued = salvage(original)
    topics, definitions, messages, run_info = _salvaged_topics(rescued.records)
    if not messages:
        raise RecordingError(f"{original.name}: corrupted beyond repair ({corruption or recording.problem}); "
                             "no message verifies")
    expected = recording.message_count if not recording.streamed else 0
    dropped = max(0, expected - len(messages))
    work = path / ".formic-repair"
    shutil.rmtree(work, ignore_errors=True)
    work.mkdir()
    staged = work / path.name
    with BagWriter(staged, typestore=typestore_from_schemas(definitions), file_name=original.name) as writer:
        for topic, info in topics.items():
            writer.add_topic(topic, info.msgtype, info.qos)
        for message in messages:
            writer.write(message.topic, message.log_time, message.data)
        writer.set_run_info({**recording.run_info, **run_info, REPAIRED_KEY: original.name + KEPT_SUFFIX})
    try:
        os.link(original, kept)
    except OSError:
        shutil.copy2(original, kept)
    os.replace(staged / original.name, original)
    os.replace(staged / "metadata.yaml", path / "metadata.yaml")
    shutil.rmtree(work)
    note = f"rewrote {len(messages)} messages with a full index; the original is kept as {kept.name}"
    if corruption:
        lost = f"dropped {dropped} messages" if expected else "dropped an unknown number of messages"
        note = (f"the file is corrupted ({corruption}); kept {len(messages)} messages that verify, {lost} "
                f"({rescued.dropped_chunks} damaged chunk(s)); the original is kept as {kept.name}")
    return RepairReport(True, len(messages), kept, note, corrupted=bool(corruption), dropped=dropped)
