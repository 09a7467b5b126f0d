"""Reading recordings (indexed, or streamed when the writer was cut short) and repairing
them (see :mod:`formic_record.bag` for the format)."""

from __future__ import annotations

import os
import shutil
from collections import Counter, deque
from collections.abc import Iterable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from mcap.reader import make_reader
from mcap.records import Channel, Message, Metadata, Schema
from rosbags.interfaces import Qos
from rosbags.rosbag2.metadata import parse_qos
from ruamel.yaml import YAML

from .bag import REPAIRED_KEY, RUN_INFO_RECORD, BagWriter, typestore_from_schemas
from .integrity import MAGIC as MCAP_MAGIC, check_integrity, readable_records, salvage

KEPT_SUFFIX = ".truncated"  # what --repair keeps of the file it replaced
REPAIR_HINT = " (formic replay --repair keeps what verifies)"


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


def _bag_info(directory: Path) -> dict[str, Any]:
    text = (directory / "metadata.yaml").read_text()
    return YAML(typ="safe").load(text)["rosbag2_bagfile_information"]


def find_mcap(path: str | os.PathLike) -> Path:
    """The MCAP file of a recording directory (or the file itself)."""
    path = Path(path)
    if path.is_file():
        return path
    if (path / "metadata.yaml").is_file():
        return path / _bag_info(path)["relative_file_paths"][0]
    files = sorted(path.glob("*.mcap"))
    if len(files) != 1:
        raise RecordingError(f"{path}: expected one .mcap file in the recording, found {len(files)}")
    return files[0]


@dataclass
class _Catalog:
    """What MCAP records declare (schemas, channels, the run info) and the messages they
    carry, counted per channel. A message whose channel or schema was not declared before it
    (a damaged chunk took the declaration with it) is skipped."""

    schemas: dict[int, Schema] = field(default_factory=dict)
    channels: dict[int, Channel] = field(default_factory=dict)
    counts: Counter[int] = field(default_factory=Counter)
    run_info: dict[str, str] = field(default_factory=dict)

    def messages(self, records: Iterable[Any], wanted: set[str] | None = None) -> Iterator[RecordedMessage]:
        for record in records:
            if isinstance(record, Schema):
                self.schemas[record.id] = record
            elif isinstance(record, Channel):
                self.channels[record.id] = record
            elif isinstance(record, Metadata) and record.name == RUN_INFO_RECORD:
                self.run_info.update(record.metadata)
            elif isinstance(record, Message) and record.channel_id in self.channels:
                channel = self.channels[record.channel_id]
                schema = self.schemas.get(channel.schema_id)
                if schema is not None:
                    self.counts[channel.id] += 1
                    if wanted is None or channel.topic in wanted:
                        yield RecordedMessage(channel.topic, schema.name, record.log_time, record.data)

    def scan(self, records: Iterable[Any]) -> "_Catalog":
        deque(self.messages(records), maxlen=0)
        return self

    def definitions(self) -> dict[str, str]:
        return {schema.name: schema.data.decode() for schema in self.schemas.values()}

    def topics(self) -> dict[str, TopicInfo]:
        return {c.topic: TopicInfo(self.schemas[c.schema_id].name, self.counts[c.id],
                                   parse_qos(c.metadata.get("offered_qos_profiles", "")))
                for c in self.channels.values() if c.schema_id in self.schemas}


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
        with self.mcap_path.open("rb") as handle:
            head = handle.read(len(MCAP_MAGIC))
        if len(head) == len(MCAP_MAGIC) and head != MCAP_MAGIC:  # shorter: cut within the magic, streamed below
            raise RecordingError(f"{self.mcap_path}: not an MCAP recording (its first bytes are not MCAP's)")
        try:
            self._scan_indexed()
        except Exception:  # noqa: BLE001 - any failure of the index means: stream it
            self.streamed = True
            self.problem = "no usable summary (the writer did not close the file)"
            self._adopt(_Catalog().scan(self._stream_records()))
            if self.stream_error:
                self.problem += f"; the streaming read stopped where the file was cut ({self.stream_error})"
        if self.metadata_path is not None and self.metadata_path.is_file():
            self.run_info.update(_bag_info(self.path).get("custom_data") or {})
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
            raise RecordingError(problem + REPAIR_HINT)

    @property
    def message_count(self) -> int:
        return sum(t.count for t in self.topics.values())

    def _scan_indexed(self) -> None:
        with self.mcap_path.open("rb") as handle:
            reader = make_reader(handle)
            summary = reader.get_summary()
            if summary is None or summary.statistics is None:
                raise RecordingError("the file has no summary section")
            counts = Counter(summary.statistics.channel_message_counts)
            catalog = _Catalog(summary.schemas, summary.channels, counts)
            self._adopt(catalog.scan(reader.iter_metadata()))

    def _adopt(self, catalog: _Catalog) -> None:
        self.schemas, self.topics = catalog.definitions(), catalog.topics()
        self.run_info.update(catalog.run_info)

    def _stream_records(self) -> Iterator[Any]:
        """Every record a streaming read reaches; stops quietly where the file was cut."""
        def stopped(exc: Exception, at: int) -> None:
            self.stream_error = f"{exc.__class__.__name__} at byte {at}"

        with self.mcap_path.open("rb") as handle:
            yield from readable_records(handle, stopped)

    def messages(self, topics: Iterable[str] | None = None) -> Iterator[RecordedMessage]:
        """Messages in log-time order (file order when streamed), optionally of some topics."""
        wanted = None if topics is None else set(topics)
        if self.streamed:
            yield from _Catalog().messages(self._stream_records(), wanted)
            return
        with self.mcap_path.open("rb") as handle:
            found = make_reader(handle, validate_crcs=True).iter_messages(
                topics=None if wanted is None else sorted(wanted), log_time_order=True)
            try:
                for schema, channel, message in found:
                    yield RecordedMessage(channel.topic, schema.name, message.log_time, message.data)
            except Exception as exc:  # noqa: BLE001 - a damaged chunk: a clean error
                detail = " ".join(str(exc).split())[:160]
                raise RecordingError(f"{self.mcap_path.name}: corrupted: {exc.__class__.__name__}: {detail}"
                                     + REPAIR_HINT) from None

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
    catalog = _Catalog()
    messages = sorted(catalog.messages(rescued.records), key=lambda m: m.log_time)
    if not messages:
        raise RecordingError(f"{original.name}: corrupted beyond repair ({corruption or recording.problem}); "
                             "no message verifies")
    expected = recording.message_count if not recording.streamed else 0
    dropped = max(0, expected - len(messages))
    work = path / ".formic-repair"
    shutil.rmtree(work, ignore_errors=True)
    work.mkdir()
    staged = work / path.name
    with BagWriter(staged, typestore=typestore_from_schemas(catalog.definitions()),
                   file_name=original.name) as writer:
        for topic, info in catalog.topics().items():
            writer.add_topic(topic, info.msgtype, info.qos)
        for message in messages:
            writer.write(message.topic, message.log_time, message.data)
        writer.set_run_info({**recording.run_info, **catalog.run_info, REPAIRED_KEY: kept.name})
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
