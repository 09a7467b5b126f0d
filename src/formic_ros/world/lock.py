"""One world per namespace and ROS domain on this machine.

Two worlds that share a namespace and a domain see each other's agents: each publishes
observations the other run's hosts answer, and each rejects the other's actions (ownership),
so both runs go wrong without failing. A world process therefore holds an exclusive lock
named after its network namespace, domain and ForMIC namespace for as long as it serves; a
second world there stops at once with an error that names the first one's process.

A file lock rather than a look at the ROS graph: the kernel drops it when its process dies,
even by SIGKILL, so a restarted world never waits out a dead one's DDS lease, and it does
not depend on discovery having finished. It covers everything that can meet with the default
loopback-only DDS (one machine and one network namespace); with ``FORMIC_DDS_NETWORK=hosts``
worlds on other machines are not seen (docs/ros.md).
"""

from __future__ import annotations

import errno
import fcntl
import os
import tempfile
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

from ..env import DOMAIN_VARIABLE
from ..errors import RunError


class WorldAlreadyServed(RunError):
    """Another world serves this namespace and domain on this machine."""


def effective_domain(domain_id: int | None) -> int:
    """The domain a process joins: ``domain_id``, else ``ROS_DOMAIN_ID``, else 0 (as rcl)."""
    if domain_id is not None:
        return domain_id
    text = os.environ.get(DOMAIN_VARIABLE, "").strip()
    return int(text) if text else 0


def _network_namespace() -> str:
    """Worlds in different network namespaces cannot meet over loopback (the tests' and the
    docs' simulated machines), so they lock apart."""
    try:
        return str(os.stat("/proc/self/ns/net").st_ino)
    except OSError:
        return "host"


def lock_path(namespace: str, domain_id: int) -> Path:
    name = namespace.strip("/").replace("/", "_") or "root"
    return Path(tempfile.gettempdir()) / f"formic-world.net{_network_namespace()}.domain{domain_id}.{name}.lock"


def _open(path: Path) -> tuple[int, bool]:
    """The lock file, and whether this process may write its pid into it."""
    try:
        return os.open(path, os.O_RDWR | os.O_CREAT, 0o666), True
    except PermissionError:  # another user's lock file: readable is enough to lock it
        return os.open(path, os.O_RDONLY), False


def _lock_or_raise(fd: int, namespace: str, domain: int) -> None:
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except OSError as error:
        if error.errno not in (errno.EWOULDBLOCK, errno.EAGAIN):
            raise
        holder = os.pread(fd, 32, 0).decode(errors="replace").strip() or "unknown"
        raise WorldAlreadyServed(
            f"another world already serves namespace {namespace} on ROS domain {domain} on this machine "
            f"(process {holder}): two runs there would answer each other's observations. Give this run a "
            f"domain of its own (--domain-id, or ROS_DOMAIN_ID) or another --namespace") from None


@contextmanager
def world_lock(namespace: str, domain_id: int | None = None) -> Iterator[Path]:
    """Hold the lock of (this machine's network namespace, ``domain_id``, ``namespace``) for the
    block; :class:`WorldAlreadyServed` when another process holds it."""
    domain = effective_domain(domain_id)
    path = lock_path(namespace, domain)
    fd, writable = _open(path)
    try:
        _lock_or_raise(fd, namespace, domain)
        if writable:
            os.ftruncate(fd, 0)
            os.pwrite(fd, str(os.getpid()).encode(), 0)
        yield path
    finally:
        os.close(fd)  # closing releases the lock


def check_world_free(namespace: str, domain_id: int | None = None) -> None:
    """:class:`WorldAlreadyServed` now, before a launcher starts any process, when another world
    serves there (the world it then starts takes the lock itself)."""
    with world_lock(namespace, domain_id):
        pass
