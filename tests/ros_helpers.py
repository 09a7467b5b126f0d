"""Spawning and reaping real ROS processes in tests: every process gets its own session, a
log file (no pipe to fill up), a hard time limit, and is SIGKILLed and reaped at the end."""

from __future__ import annotations

import json
import os
import random
import signal
import subprocess
import sys
import time
from pathlib import Path

from formic_ros.env import ros_environment
from formic_ros.launch.processes import remove_stale_shm

ROOT = Path(__file__).resolve().parents[1]
_domains = random.Random(os.getpid() ^ int(time.time()))


def _worker_domains() -> range:
    """This pytest process's share of domains 120-219 (away from the default 0 and from ids people
    pick by hand): all of it, or under pytest-xdist (``-n N``) the N-th part that worker N owns,
    so that tests running side by side never meet in one domain."""
    workers = int(os.environ.get("PYTEST_XDIST_WORKER_COUNT", "1"))
    worker = int(os.environ.get("PYTEST_XDIST_WORKER", "gw0").removeprefix("gw"))
    share = 100 // workers
    return range(120 + worker * share, 120 + (worker + 1) * share)


def fresh_domain_id() -> int:
    """A ROS domain for one test, random in this worker's share, so concurrent test runs on
    this machine do not mix."""
    return _domains.choice(_worker_domains())


def ros_test_environment(domain_id: int) -> dict[str, str]:
    """Localhost discovery, this test's domain, UDPv4 only (no shared-memory files that a
    SIGKILL leaves behind)."""
    env = ros_environment(domain_id)
    env["FASTDDS_BUILTIN_TRANSPORTS"] = "UDPv4"
    return env


class Proc:
    """A spawned process with its output in a file."""

    def __init__(self, args: list[str], env: dict[str, str], log: Path, limit_s: float):
        self.args = args
        self.log_path = log
        self._log = open(log, "wb")
        self.limit_s = limit_s
        self.started = time.monotonic()
        self.popen = subprocess.Popen(args, env=env, stdout=self._log, stderr=subprocess.STDOUT,
                                      stdin=subprocess.DEVNULL, start_new_session=True, cwd=ROOT)

    @property
    def pid(self) -> int:
        return self.popen.pid

    def alive(self) -> bool:
        return self.popen.poll() is None

    def output(self) -> str:
        if not self._log.closed:
            self._log.flush()
        return self.log_path.read_text(errors="replace")

    def wait(self, timeout: float | None = None) -> int:
        """Exit status; a process still running after ``timeout`` (default: what is left of
        its limit) is killed and the test fails."""
        left = self.limit_s - (time.monotonic() - self.started) if timeout is None else timeout
        try:
            return self.popen.wait(timeout=max(0.1, left))
        except subprocess.TimeoutExpired:
            self.kill()
            raise AssertionError(f"{self.args} did not finish in time; output:\n{self.output()[-3000:]}")

    def wait_for_text(self, text: str, timeout: float) -> None:
        deadline = time.monotonic() + timeout
        while text not in self.output():
            if not self.alive():
                raise AssertionError(f"{self.args} exited before printing {text!r}:\n{self.output()[-3000:]}")
            if time.monotonic() > deadline:
                raise AssertionError(f"no {text!r} from {self.args} in {timeout} s:\n{self.output()[-3000:]}")
            time.sleep(0.05)

    def kill(self) -> None:
        """SIGKILL the whole process group and reap."""
        if self.alive():
            try:
                os.killpg(self.pid, signal.SIGKILL)
            except ProcessLookupError:
                pass
        self.popen.wait()
        self._log.close()

    def json_line(self) -> dict:
        """The last line of the output that parses as a JSON object."""
        for line in reversed(self.output().splitlines()):
            if line.startswith("{"):
                return json.loads(line)
        raise AssertionError(f"no JSON in the output of {self.args}:\n{self.output()[-3000:]}")


class Spawner:
    """Starts ``formic`` commands and scripts for one test; :meth:`reap_all` kills what is left."""

    def __init__(self, log_dir: Path, domain_id: int):
        self.log_dir = log_dir
        self.domain_id = domain_id
        self.env = ros_test_environment(domain_id)
        self.procs: list[Proc] = []

    def formic(self, name: str, *args: str, limit_s: float = 90.0) -> Proc:
        return self.python(name, "-m", "formic_cli.main", *args, limit_s=limit_s)

    def python(self, name: str, *args: str, limit_s: float = 90.0) -> Proc:
        proc = Proc([sys.executable, *args], self.env, self.log_dir / f"{name}.log", limit_s)
        self.procs.append(proc)
        return proc

    def reap_all(self) -> None:
        for proc in self.procs:
            proc.kill()
        remove_stale_shm()  # the shared memory of processes killed here (once old enough)


def descendants(pid: int) -> set[int]:
    """Every process below ``pid`` (children, grandchildren, ...), from /proc."""
    parents: dict[int, list[int]] = {}
    for entry in Path("/proc").iterdir():
        if entry.name.isdigit():
            try:
                stat = (entry / "stat").read_text()
            except OSError:
                continue
            ppid = int(stat.rsplit(")", 1)[1].split()[1])
            parents.setdefault(ppid, []).append(int(entry.name))
    found, todo = set(), [pid]
    while todo:
        for child in parents.get(todo.pop(), []):
            if child not in found:
                found.add(child)
                todo.append(child)
    return found


def running(pid: int) -> bool:
    """Whether ``pid`` exists and is not a zombie."""
    try:
        stat = Path(f"/proc/{pid}/stat").read_text()
    except OSError:
        return False
    return stat.rsplit(")", 1)[1].split()[0] != "Z"
