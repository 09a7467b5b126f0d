"""The launcher's child processes: start one node process in a session of its own (so a
terminal's Ctrl-C reaches only the launcher, which then stops the children in order) and with a
parent-death signal (so even a SIGKILLed launcher leaves no orphans); stop it with SIGINT, then
SIGTERM, then SIGKILL to its whole process group, each after a grace period, and reap it; its
log file; the JSON lines it prints; the shared-memory files of Fast DDS processes that died
without removing them. While a launch holds children, the first SIGINT, SIGTERM or SIGHUP
stops it and later ones cannot cut the stop short (:class:`Children`)."""

from __future__ import annotations

import ctypes
import fcntl
import json
import os
import signal
import subprocess
import sys
import tempfile
import time
from contextlib import suppress
from dataclasses import dataclass
from pathlib import Path

from formic_runtime.signals import STOP_SIGNALS, FirstStopInterrupts, handling

from .node_process import error_file

STOP_GRACE_S = (5.0, 3.0)  # after SIGINT, after SIGTERM; then SIGKILL
RECORDER_GRACE_S = (20.0, 5.0)  # the recorder closes its file on SIGINT
PR_SET_PDEATHSIG = 1

_libc = ctypes.CDLL(None, use_errno=True) if sys.platform.startswith("linux") else None


def _die_with_parent() -> None:
    """Runs in the child between fork and exec: SIGKILL me when the launcher dies."""
    if _libc is not None:
        _libc.prctl(PR_SET_PDEATHSIG, signal.SIGKILL)


@dataclass
class Child:
    """A spawned process and how to stop it."""

    name: str
    process: subprocess.Popen
    grace_s: tuple[float, float] = STOP_GRACE_S  # after SIGINT, after SIGTERM
    error_path: Path | None = None  # where the node process leaves its error message (node_process.error_file)

    def error(self) -> str:
        """Why the child failed, in one line naming it: its own error message, or its status."""
        message = self.error_path.read_text().strip() if self.error_path and self.error_path.exists() else ""
        if message:
            return f"{self.name}: {message}"
        return f"{self.name} exited with status {self.process.returncode} (see its log)"

    @property
    def alive(self) -> bool:
        return self.poll() is None

    @property
    def failed(self) -> bool:
        """Exited with a non-zero status."""
        return bool(self.poll())

    def poll(self, block: bool = False) -> int | None:
        """The exit status, or None while it runs. Not Popen.poll/wait: they take a lock that a
        KeyboardInterrupt landing between its acquire and its ``try`` leaves held, after which
        every wait blocks forever (a launcher rarely hung on Ctrl-C); ``os.waitpid`` holds none."""
        if self.process.returncode is None:
            try:
                pid, status = os.waitpid(self.process.pid, 0 if block else os.WNOHANG)
            except ChildProcessError:  # reaped, its status lost to an interrupt: it has exited
                self.process.returncode = -1
            else:
                if pid:
                    self.process.returncode = os.waitstatus_to_exitcode(status)
        return self.process.returncode

    def signal(self, signum: int) -> None:
        with suppress(ProcessLookupError):
            os.killpg(self.process.pid, signum)

    def wait(self, timeout_s: float) -> None:
        """Wait up to ``timeout_s`` for the child to exit (it may still run afterwards)."""
        deadline = time.monotonic() + timeout_s
        while self.alive and time.monotonic() < deadline:
            time.sleep(min(0.02, max(0.0, deadline - time.monotonic())))


SHM_DIR = Path("/dev/shm")
SHM_MIN_AGE_S = 10.0  # younger files are left alone: their process may not have locked them yet


def remove_stale_shm(directory: Path = SHM_DIR) -> int:
    """Remove Fast DDS shared-memory segments and ports whose owner has died (a SIGKILLed node
    cannot remove its own): each has a lock file (``..._el`` or ``..._sl``) that a live owner holds
    locked, so one we can lock is stale. Returns the number removed."""
    removed = 0
    for lock in directory.glob("fastrtps_*_[es]l"):
        try:
            if time.time() - lock.stat().st_mtime < SHM_MIN_AGE_S:
                continue
            with open(lock, "ab") as handle:
                fcntl.flock(handle, fcntl.LOCK_EX | fcntl.LOCK_NB)  # OSError: in use
        except OSError:
            continue
        base = lock.name[:-3]
        for name in (base, lock.name, f"sem.{base}_mutex"):  # the segment, its lock, a port's mutex
            (directory / name).unlink(missing_ok=True)
        removed += 1
    return removed


def stop_all(children: list[Child]) -> dict[str, int]:
    """Stop every child at once: SIGINT to all, then SIGTERM to those still running, then
    SIGKILL, each step waiting on one shared deadline (the slowest child's grace), so a launch
    with many children stops as fast as its slowest one; reaps them and returns their statuses."""
    for step, signum in enumerate((signal.SIGINT, signal.SIGTERM)):
        running = [child for child in children if child.alive]
        for child in running:
            child.signal(signum)
        deadline = time.monotonic() + max((child.grace_s[step] for child in running), default=0.0)
        for child in running:
            child.wait(deadline - time.monotonic())
    for child in children:
        if child.alive:
            child.signal(signal.SIGKILL)
    return {child.name: child.poll(block=True) for child in children}


def watch(main: Child, others: list[Child], timeout_s: float | None, what: str, poll_s: float = 0.2,
          required: Child | None = None, tick=None) -> None:
    """Until ``main`` exits (with status 0, else RuntimeError), calling ``tick`` every ``poll_s``.
    One of ``others`` failing, ``required`` leaving, or ``timeout_s`` passing first is an error."""
    deadline = None if timeout_s is None else time.monotonic() + timeout_s
    while main.alive:
        if required is not None and not required.alive:
            raise RuntimeError(required.error() if required.failed else f"the {required.name} exited early")
        for child in others:
            if child.failed:
                raise RuntimeError(child.error())
        if deadline is not None and time.monotonic() > deadline:
            raise RuntimeError(f"{what} did not finish within {timeout_s} s")
        if tick is not None:
            tick()
        main.wait(poll_s)
    if main.process.returncode != 0:
        raise RuntimeError(main.error())


class Children:
    """The child processes of one launch, as a context: on exit every child is stopped (all
    at once, :func:`stop_all`) and reaped, its files closed, the launch's temporary directory
    :attr:`dir` (option files, stdout files) and stale shared memory removed; exit statuses in
    :attr:`codes`. A child's log goes to stderr, or to ``LOG_DIR/NAME.log``.

    Inside the context (in the main thread) the first stop signal raises KeyboardInterrupt;
    later ones, and any during the stop, are ignored (:mod:`formic_runtime.signals`): a second Ctrl-C,
    ``timeout``'s SIGTERM to the command and then to its group, or a closing terminal's SIGHUP
    would otherwise end the launcher mid-stop, and the parent-death signal would SIGKILL a
    recorder before it closed its file."""

    def __init__(self, prefix: str, env: dict[str, str], log_dir: str | None):
        self._tmp = tempfile.TemporaryDirectory(prefix=prefix)
        self.dir, self.env, self.log_dir = Path(self._tmp.name), env, log_dir
        self.children: list[Child] = []
        self.files: list = []
        self.codes: dict[str, int] = {}
        self._stop_rule = FirstStopInterrupts()
        self._signals = handling(STOP_SIGNALS, self._stop_rule)

    def __enter__(self) -> Children:
        self._signals.__enter__()
        return self

    def __exit__(self, *exc) -> None:
        self._stop_rule.stop()
        try:
            self.codes = stop_all(self.children)
        finally:
            for file in self.files:
                file.close()
            self._tmp.cleanup()
            remove_stale_shm()  # what a child killed with SIGKILL left behind
            self._signals.__exit__(None, None, None)

    def start(self, name: str, spec: dict, stdout=None, grace_s: tuple[float, float] = STOP_GRACE_S) -> Child:
        """Start node process ``name`` (:mod:`formic_ros.launch.node_process`) on ``spec``, written as
        ``DIR/NAME.options.json``, in its own session and killed if this process dies; its output
        (stdout too, unless given) to its log."""
        log = sys.stderr
        if self.log_dir is not None:
            Path(self.log_dir).mkdir(parents=True, exist_ok=True)
            log = open(Path(self.log_dir) / f"{name}.log", "w")
            self.files.append(log)
        out, err = (stdout, log) if stdout is not None else (log, subprocess.STDOUT)
        options = self.dir / f"{name}.options.json"
        options.write_text(json.dumps(spec))
        process = subprocess.Popen(
            [sys.executable, "-m", "formic_ros.launch.node_process", "--options", str(options)], env=self.env,
            stdout=out, stderr=err, stdin=subprocess.DEVNULL, start_new_session=True,
            preexec_fn=_die_with_parent,
        )
        self.children.append(Child(name, process, grace_s, error_file(options)))
        return self.children[-1]

    def stdout(self, name: str):
        """A file in :attr:`dir` for a child's stdout (read back with :class:`JsonLines`)."""
        self.files.append(open(self.dir / f"{name}.json", "w+b"))
        return self.files[-1]


class JsonLines:
    """The JSON objects a child prints to a file, one a line, read as they come."""

    def __init__(self, file):
        self.file, self.offset, self.partial = file, 0, b""

    def new(self) -> list[dict]:
        """The objects printed since the last call (a line still being written waits)."""
        self.file.seek(self.offset)
        data = self.file.read()
        self.offset += len(data)
        *lines, self.partial = (self.partial + data).split(b"\n")
        return [json.loads(line) for line in lines if line.startswith(b"{")]
