"""Is an MCAP file intact? Every CRC the format carries is checked: each chunk's (of its
uncompressed records), the data section's (``DataEnd``) and the summary section's (``Footer``).
Corruption is one line of text (what failed, where), never an exception a user sees.

A file cut short (a writer killed) is not corrupted: it ends early, and what reached the
disk still verifies. :func:`salvage` keeps every record of every chunk that verifies.
"""

from __future__ import annotations

import struct
import zlib
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, BinaryIO

from mcap.records import Chunk, Footer
from mcap.stream_reader import StreamReader, breakup_chunk

MAGIC = b"\x89MCAP0\r\n"
FOOTER_BYTES = 1 + 8 + 8 + 8 + 4  # opcode, length, summary_start, summary_offset_start, summary_crc


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


def salvage(path: str | Path) -> Salvage:
    """Every record that verifies: chunks whose CRC or decompression fails are dropped
    (counted); the read ends where the record structure itself is broken."""
    out = Salvage()

    def stopped(exc: Exception, at: int) -> None:
        out.problems.append(f"reading stopped near byte {at}: {_describe(exc)}")

    with Path(path).open("rb") as handle:
        for record in readable_records(handle, stopped, emit_chunks=True):
            if isinstance(record, Footer):
                break
            if not isinstance(record, Chunk):
                out.records.append(record)
                continue
            try:
                out.records.extend(breakup_chunk(record, validate_crc=True))
            except Exception as exc:  # noqa: BLE001 - a chunk that does not verify is dropped
                out.dropped_chunks += 1
                out.problems.append(f"chunk ending near byte {handle.tell()}: {_describe(exc)}")
    return out
