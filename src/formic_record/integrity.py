"""Is an MCAP file intact? Every CRC the format carries is checked: each chunk's (of its
uncompressed records), the data section's (``DataEnd``) and the summary section's (``Footer``).
Corruption is one line of text (what failed, where), never an exception a user sees.

A file cut short (a writer killed) is not corrupted: it ends early, and what reached the
disk still verifies. :func:`salvage` keeps every record of every chunk that verifies, found by
scanning the file for chunk records rather than by following indexes or record lengths that
may themselves be damaged.
"""

from __future__ import annotations

import mmap
import struct
import zlib
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from io import BytesIO
from pathlib import Path
from typing import Any, BinaryIO

from mcap.data_stream import ReadDataStream
from mcap.opcode import Opcode
from mcap.records import Chunk, Footer
from mcap.stream_reader import StreamReader, breakup_chunk

MAGIC = b"\x89MCAP0\r\n"
FOOTER_BYTES = 1 + 8 + 8 + 8 + 4  # opcode, length, summary_start, summary_offset_start, summary_crc
RECORD_HEAD = 1 + 8  # opcode, length
CHUNK_HEAD = 8 + 8 + 8 + 4  # message start and end time, uncompressed size and CRC (then the compression)
CHUNK_OPCODE = bytes([Opcode.CHUNK])
COMPRESSIONS = (b"", b"zstd", b"lz4")
KEPT_OUTSIDE_CHUNKS = (Opcode.SCHEMA, Opcode.CHANNEL, Opcode.MESSAGE, Opcode.METADATA)  # not indexes: rebuilt


def _describe(exc: BaseException) -> str:
    text = " ".join(str(exc).split()) or exc.__class__.__name__
    return f"{exc.__class__.__name__}: {text}"[:200]


def readable_records(handle: BinaryIO, stopped: Callable[[Exception, int], None],
                     **options: Any) -> Iterator[Any]:
    """The records of a streaming read (``StreamReader`` options), ending quietly where they
    no longer parse; ``stopped`` is told why and at which byte."""
    try:
        yield from StreamReader(handle, **options).records
    except Exception as exc:  # noqa: BLE001 - a truncated or broken record ends the readable part
        stopped(exc, handle.tell())


def read_footer(path: Path) -> tuple[int, int, int] | None:
    """The footer's offset, summary start and summary CRC; None unless the file ends in a
    footer and the closing magic (the writer finished it)."""
    at = path.stat().st_size - len(MAGIC) - FOOTER_BYTES
    if at < len(MAGIC):
        return None
    with path.open("rb") as handle:
        handle.seek(at)
        tail = handle.read()
    if tail[-len(MAGIC):] != MAGIC or tail[0] != 0x02:
        return None
    summary_start, _, crc = struct.unpack("<QQI", tail[9:FOOTER_BYTES])
    return at, summary_start, crc


def summary_problem(path: Path, footer: tuple[int, int, int]) -> str | None:
    """The footer's CRC over the summary section (the ``mcap`` reader does not check it)."""
    at, summary_start, crc = footer
    if crc == 0:
        return None
    if summary_start > at:
        return f"footer at byte {at}: summary start {summary_start} is past the end"
    start, end = summary_start or at, at + FOOTER_BYTES - 4  # the CRC covers all up to itself
    with path.open("rb") as handle:
        handle.seek(start)
        actual = zlib.crc32(handle.read(end - start))
    if actual != crc:
        return (f"summary section (bytes {start}-{end}): CRC mismatch "
                f"(footer says {crc:#010x}, bytes give {actual:#010x})")
    return None


def check_integrity(path: str | Path) -> str | None:
    """None when every CRC verifies, else the first failure as one line. A file without a
    footer (cut short) is only checked up to where it ends."""
    path = Path(path)
    footer = read_footer(path)
    with path.open("rb") as handle:
        try:
            for record in StreamReader(handle, validate_crcs=True).records:
                if isinstance(record, Footer):
                    break
        except Exception as exc:  # noqa: BLE001 - any failure here is the answer
            ended = handle.tell() >= path.stat().st_size
            if footer is None and ended and "crc" not in str(exc).lower():
                return None  # cut short: the readable part ends with the file
            return f"{path.name}: corrupted near byte {handle.tell()}: {_describe(exc)}"
    problem = footer and summary_problem(path, footer)
    return f"{path.name}: corrupted: {problem}" if problem else None


@dataclass
class Salvage:
    records: list[Any] = field(default_factory=list)  # schemas, channels, messages, metadata
    dropped_chunks: int = 0
    problems: list[str] = field(default_factory=list)


def _chunk_length(data: mmap.mmap, at: int) -> int | None:
    """The length of the chunk record at ``at`` when its framing holds together (a known
    compression, a data length that fills the record exactly, all inside the file), else None:
    a cheap test before a candidate is parsed and its CRC checked."""
    head = at + RECORD_HEAD + CHUNK_HEAD
    if head + 4 > len(data):
        return None
    (length,) = struct.unpack_from("<Q", data, at + 1)
    (name_bytes,) = struct.unpack_from("<I", data, head)
    if name_bytes > 4 or at + RECORD_HEAD + length > len(data):
        return None
    if data[head + 4:head + 4 + name_bytes] not in COMPRESSIONS:
        return None
    (data_bytes,) = struct.unpack_from("<Q", data, head + 4 + name_bytes)
    return length if CHUNK_HEAD + 4 + name_bytes + 8 + data_bytes == length else None


def _verified_chunks(data: mmap.mmap, out: Salvage) -> Iterator[tuple[int, int, list[Any]]]:
    """(start, end, records) of every chunk record whose CRC verifies, in file order, found by
    scanning for the chunk opcode: no damaged index or record length can hide one."""
    at = data.find(CHUNK_OPCODE, len(MAGIC))
    while at != -1:
        length = _chunk_length(data, at)
        if length is not None:
            end = at + RECORD_HEAD + length
            try:
                records = breakup_chunk(Chunk.read(ReadDataStream(BytesIO(data[at + RECORD_HEAD:end]))),
                                        validate_crc=True)
            except Exception as exc:  # noqa: BLE001 - a chunk that does not verify is dropped
                out.dropped_chunks += 1
                out.problems.append(f"chunk at byte {at}: {_describe(exc)}")
            else:
                yield at, end, records
                at = data.find(CHUNK_OPCODE, end)
                continue
        at = data.find(CHUNK_OPCODE, at + 1)


def _records_between(data: mmap.mmap, start: int, end: int, out: Salvage) -> Iterator[Any]:
    """The records between two chunks that verify (metadata; schemas, channels and messages some
    writers put outside chunks), each parsed within its own length; index records are skipped
    (a repair rebuilds them). The walk ends at the summary section or where the framing breaks."""
    at = start
    while at + RECORD_HEAD <= end:
        opcode, length = struct.unpack_from("<BQ", data, at)
        if opcode in (Opcode.DATA_END, Opcode.FOOTER):
            return
        if at + RECORD_HEAD + length > end:
            out.problems.append(f"record at byte {at} runs past byte {end}: skipped up to there")
            return
        if opcode in KEPT_OUTSIDE_CHUNKS:
            try:
                yield next(StreamReader(BytesIO(data[at:at + RECORD_HEAD + length]), skip_magic=True).records)
            except Exception as exc:  # noqa: BLE001 - a record that does not parse is dropped
                out.problems.append(f"record at byte {at}: {_describe(exc)}")
        at += RECORD_HEAD + length


def salvage(path: str | Path) -> Salvage:
    """Every record that verifies, in file order: each chunk whose CRC verifies, wherever it
    lies, and the records between them that parse. Chunks that do not verify are dropped
    (counted); a damaged index or record outside a chunk costs no chunk."""
    out = Salvage()
    path = Path(path)
    if path.stat().st_size <= len(MAGIC):
        return out
    with path.open("rb") as handle, mmap.mmap(handle.fileno(), 0, access=mmap.ACCESS_READ) as data:
        at = len(MAGIC)
        for start, end, records in _verified_chunks(data, out):
            out.records.extend(_records_between(data, at, start, out))
            out.records.extend(records)
            at = end
        out.records.extend(_records_between(data, at, len(data), out))
    return out
