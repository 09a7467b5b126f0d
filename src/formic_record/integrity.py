"""Is an MCAP file intact? Every CRC the format carries is checked: each chunk's (of its
uncompressed records), the data section's (``DataEnd``) and the summary section's (``Footer``).
Corruption is one line of text (what failed, where), never an exception a user sees.

A file cut short (a writer killed) is not corrupted: it ends early, and what reached the
disk still verifies. :func:`salvage` keeps every record of every chunk that verifies.
"""

from __future__ import annotations

import struct
import zlib
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from mcap.records import Chunk, Footer, Message
from mcap.stream_reader import StreamReader, breakup_chunk

MAGIC = b"\x89MCAP0\r\n"
FOOTER_BYTES = 1 + 8 + 8 + 8 + 4  # opcode, length, summary_start, summary_offset_start, summary_crc


def _describe(exc: BaseException) -> str:
    text = " ".join(str(exc).split()) or exc.__class__.__name__
    return f"{exc.__class__.__name__}: {text}"[:200]


def has_footer(path: Path) -> bool:
    """The file ends in a footer and the closing magic (the writer finished it)."""
    size = path.stat().st_size
    if size < len(MAGIC) * 2 + FOOTER_BYTES:
        return False
    with path.open("rb") as handle:
        handle.seek(size - len(MAGIC) - FOOTER_BYTES)
        tail = handle.read()
    return tail[-len(MAGIC):] == MAGIC and tail[0] == 0x02


def summary_problem(path: Path) -> str | None:
    """The footer's CRC over the summary section (the ``mcap`` reader does not check it)."""
    size = path.stat().st_size
    with path.open("rb") as handle:
        handle.seek(size - len(MAGIC) - FOOTER_BYTES)
        footer = handle.read(FOOTER_BYTES)
        summary_start, _, crc = struct.unpack("<QQI", footer[9:])
        if crc == 0:
            return None
        if summary_start == 0:
            start = size - len(MAGIC) - FOOTER_BYTES
        elif summary_start > size - len(MAGIC) - FOOTER_BYTES:
            return f"footer at byte {size - len(MAGIC) - FOOTER_BYTES}: summary start {summary_start} is past the end"
        else:
            start = summary_start
        handle.seek(start)
        covered = handle.read(size - len(MAGIC) - 4 - start)
    actual = zlib.crc32(covered)
    if actual != crc:
        return (f"summary section (bytes {start}-{size - len(MAGIC) - 4}): CRC mismatch "
                f"(footer says {crc:#010x}, bytes give {actual:#010x})")
    return None


def check_integrity(path: str | Path) -> str | None:
    """None when every CRC verifies, else the first failure as one line. A file without a
    footer (cut short) is only checked up to where it ends."""
    path = Path(path)
    complete = has_footer(path)
    with path.open("rb") as handle:
        try:
            for record in StreamReader(handle, validate_crcs=True).records:
                if isinstance(record, Footer):
                    break
        except Exception as exc:  # noqa: BLE001 - any failure here is the answer
            ended = handle.tell() >= path.stat().st_size
            if not complete and ended and "crc" not in str(exc).lower():
                return None  # cut short: the readable part ends with the file
            return f"{path.name}: corrupted near byte {handle.tell()}: {_describe(exc)}"
    if complete:
        problem = summary_problem(path)
        if problem:
            return f"{path.name}: corrupted: {problem}"
    return None


@dataclass
class Salvage:
    records: list[Any] = field(default_factory=list)  # schemas, channels, messages, metadata
    dropped_chunks: int = 0
    problems: list[str] = field(default_factory=list)

    @property
    def messages(self) -> int:
        return sum(isinstance(r, Message) for r in self.records)


def salvage(path: str | Path) -> Salvage:
    """Every record that verifies: chunks whose CRC or decompression fails are dropped
    (counted); the read ends where the record structure itself is broken."""
    path = Path(path)
    out = Salvage()
    with path.open("rb") as handle:
        records: Iterator[Any] = StreamReader(handle, emit_chunks=True).records
        while True:
            try:
                record = next(records)
            except StopIteration:
                break
            except Exception as exc:  # noqa: BLE001 - the rest of the file cannot be parsed
                out.problems.append(f"reading stopped near byte {handle.tell()}: {_describe(exc)}")
                break
            if isinstance(record, Chunk):
                try:
                    out.records.extend(breakup_chunk(record, validate_crc=True))
                except Exception as exc:  # noqa: BLE001 - a chunk that does not verify is dropped
                    out.dropped_chunks += 1
                    out.problems.append(f"chunk ending near byte {handle.tell()}: {_describe(exc)}")
            elif isinstance(record, Footer):
                break
            else:
                out.records.append(record)
    return out
