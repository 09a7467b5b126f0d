"""Writing files atomically: through a temporary file in the same directory, fsynced and then
renamed over the target, so a crash leaves the old file or the new one, never half of one. And
holding a directory, so that two processes never write one run's files at once."""

from __future__ import annotations

import fcntl
import os
import tempfile
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import IO

from .errors import InputError


@contextmanager
def atomic_open(path: str | os.PathLike, mode: str = "w", **kwargs) -> Iterator[IO]:
    """A handle whose content replaces ``path`` when the block ends without an exception (the
    file is world-readable, 0644: scenario sets, models and results are meant to be shared)."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    try:
        with os.fdopen(fd, mode, **kwargs) as handle:
            yield handle
            handle.flush()
            os.fsync(handle.fileno())
        os.chmod(tmp, 0o644)  # mkstemp creates 0600
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise



@contextmanager
def held_directory(path: str | os.PathLike) -> Iterator[Path]:
    """Hold ``path`` (an advisory lock on ``path/.lock``, which names the holder's pid) while the
    block runs: a second process asking for it fails at once with an InputError instead of
    writing over the first one's checkpoints. The kernel drops the lock when its process ends,
    killed or not, so nothing stale is left behind."""
    path = Path(path)
    path.mkdir(parents=True, exist_ok=True)
    handle = open(path / ".lock", "a+")
    try:
        fcntl.flock(handle, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except BlockingIOError:
        handle.seek(0)
        holder = handle.read().strip()
        handle.close()
        raise InputError(f"{path} is in use by another process{f' (pid {holder})' if holder else ''}: "
                         "one run per directory") from None
    try:
        handle.seek(0)
        handle.truncate()
        handle.write(f"{os.getpid()}\n")
        handle.flush()
        yield path
    finally:
        handle.close()
