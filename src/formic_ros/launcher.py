"""``formic run``: the world, the agent hosts (or the planner) and optionally the recorder as
separate ROS processes, one episode, a summary, and nothing left behind.

Each child runs ``python -m formic_cli.main <command>`` in a session of its own (so a terminal's
Ctrl-C reaches only the launcher, which then stops the children in order) and with a parent-death
signal (so even a SIGKILLed launcher leaves no orphans). Stopping is SIGINT, then SIGTERM, then
SIGKILL to the child's whole process group, each after a grace period, and every child is
reaped. The world waits for every agent before step 0 (discovery; with ``--record`` also for
the recorder's subscriptions), plays the episode and prints its summary as one JSON line,
which the launcher reads from the world's stdout.
"""

from __future__ import annotations

import ctypes
import json
import math
import os
import signal
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

from formic_agent.registry import DEFAULT_MODEL, TeamAssignment, parse_team
from formic_world import Scenario

from . import qos
from .env import check_domain_id, ros_environment

SHARED_MARK_POLICIES = ("csaf", "csaf11", "cardinality")  # one team's marks live in one process
STOP_GRACE_S = (5.0, 3.0)  # after SIGINT, after SIGTERM; then SIGKILL
RECORDER_GRACE_S = (20.0, 5.0)  # the recorder closes its file on SIGINT
HOST_EXIT_S = 10.0  # how long hosts get to leave by themselves after the episode
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

    @property
    def alive(self) -> bool:
        return self.process.poll() is None

    def signal(self, signum: int) -> None:
        try:
            os.killpg(self.process.pid, signum)
        except ProcessLookupError:
            pass

    def stop(self, grace_s: tuple[float, float] = STOP_GRACE_S) -> int:
        """SIGINT, SIGTERM, SIGKILL (to the process group), waiting ``grace_s`` in between;
        reaps the child and returns its exit status."""
        for signum, grace in ((signal.SIGINT, grace_s[0]), (signal.SIGTERM, grace_s[1])):
            if not self.alive:
                break
            self.signal(signum)
            try:
                self.process.wait(timeout=grace)
            except subprocess.TimeoutExpired:
                pass
        if self.alive:
            self.signal(signal.SIGKILL)
        return self.process.wait()


def spawn(name: str, args: list[str], env: dict[str, str], stdout=None, stderr=None) -> Child:
    """Start ``formic <args>`` as a child in its own session, killed if this process dies."""
    command = [sys.executable, "-m", "formic_cli.main", *args]
    process = subprocess.Popen(
        command, env=env, stdout=stdout, stderr=stderr, stdin=subprocess.DEVNULL,
        start_new_session=True, preexec_fn=_die_with_parent,
    )
    return Child(name, process)


def split_team(team: TeamAssignment, hosts: int) -> list[list[int]]:
    """Agents of each host: a team of a shared-mark baseline stays whole in one host; the
    other agents are dealt in contiguous chunks so hosts end up about equally loaded."""
    buckets: list[list[int]] = [[] for _ in range(max(1, hosts))]
    splittable: list[int] = []
    for name, ids in team.groups:
        if name in SHARED_MARK_POLICIES:
            min(buckets, key=len).extend(ids)
        else:
            splittable.extend(ids)
    splittable.sort()
    target = math.ceil((sum(map(len, buckets)) + len(splittable)) / len(buckets))
    start = 0
    for bucket in buckets:
        take = max(0, target - len(bucket))
        bucket.extend(splittable[start:start + take])
        start += take
    buckets[-1].extend(splittable[start:])
    return [sorted(b) for b in buckets if b]


def ids_text(ids: list[int]) -> str:
    return ",".join(map(str, ids))


@dataclass
class RunOptions:
    scenario: Scenario
    policy: str = "formic"  # team spec, e.g. formic:0-15,csaf11:16-31
    model: str | None = None
    greedy: bool = False
    hosts: int = 1
    transport: str = "per-agent"
    external: tuple[int, ...] = ()
    record: str | None = None
    namespace: str = qos.DEFAULT_NAMESPACE
    domain_id: int | None = None
    deadline_ms: float = 1000.0
    startup_timeout_s: float = 60.0
    rate_hz: float | None = None
    viewer_every: int = 10
    progress: bool = False
    log_dir: str | None = None  # children's output there (one file each) instead of stderr
    timeout_s: float | None = None  # give up on the world after this long


def world_command(opts: RunOptions, scenario_file: Path, label: str) -> list[str]:
    args = [
        "world", "--scenario", str(scenario_file), "--policy-label", label, "--namespace", opts.namespace,
        "--deadline-ms", str(opts.deadline_ms), "--startup-timeout", str(opts.startup_timeout_s),
        "--viewer-every", str(opts.viewer_every), "--json",
    ]
    if opts.rate_hz:
        args += ["--rate", str(opts.rate_hz)]
    if opts.progress:
        args.append("--progress")
    if opts.record:  # the recorder must hear step 0
        args += ["--require-subscriber", qos.APPLIED_ACTIONS, "--require-subscriber", qos.STATE]
    return args


def recorder_command(opts: RunOptions, team: TeamAssignment) -> list[str]:
    args = ["record", "--out", opts.record, "--namespace", opts.namespace]
    if "formic" in dict(team.groups):
        args += ["--model", str(opts.model or DEFAULT_MODEL)]
    return args


def driver_commands(opts: RunOptions, team: TeamAssignment) -> dict[str, list[str]]:
    """The processes that answer the world: the planner node, or the agent hosts."""
    if "planner" in dict(team.groups):
        return {"planner": ["planner", "--namespace", opts.namespace, "--once"]}
    commands = {}
    for i, ids in enumerate(split_team(team, opts.hosts)):
        args = ["agents", "--ids", ids_text(ids), "--policy", opts.policy, "--transport", opts.transport,
                "--namespace", opts.namespace, "--name", f"agent_host_{i}", "--once"]
        if opts.model:
            args += ["--model", opts.model]
        if opts.greedy:
            args.append("--greedy")
        commands[f"host{i}"] = args
    return commands


def _wait_for_world(world: Child, recorder: Child | None, drivers: list[Child], timeout_s: float | None) -> None:
    """Until the world exits. The recorder leaving, or a host or the planner failing, before
    that is an error (the episode would run on without them; a failure is a bug to report)."""
    deadline = None if timeout_s is None else time.monotonic() + timeout_s
    while world.alive:
        if recorder is not None and not recorder.alive:
            raise RuntimeError(f"the recorder exited early with status {recorder.process.returncode}")
        for child in drivers:
            if child.process.poll():
                raise RuntimeError(f"{child.name} failed with status {child.process.returncode} (see its log)")
        if deadline is not None and time.monotonic() > deadline:
            raise RuntimeError(f"the world did not finish within {timeout_s} s")
        try:
            world.process.wait(timeout=0.2)
        except subprocess.TimeoutExpired:
            pass


def launch(opts: RunOptions) -> dict:
    """Play one episode across processes; returns the world's summary (plus launch details).
    Raises RuntimeError when the world fails; children are stopped and reaped in any case."""
    team = parse_team(opts.policy, opts.scenario.config.n_agents, external=opts.external)
    if "planner" in dict(team.groups) and opts.external:
        raise ValueError("the planner commands every agent; it cannot leave some to --external")
    check_domain_id(opts.domain_id)
    env = ros_environment(opts.domain_id)
    label = opts.policy + (f",external:{ids_text(list(opts.external))}" if opts.external else "")
    children: list[Child] = []
    files = []  # output files, closed at the end
    started = time.monotonic()
    with tempfile.TemporaryDirectory(prefix="formic-run-") as tmp:

        def output(name: str):
            if opts.log_dir is None:
                return sys.stderr
            Path(opts.log_dir).mkdir(parents=True, exist_ok=True)
            files.append(open(Path(opts.log_dir) / f"{name}.log", "w"))
            return files[-1]

        scenario_file = Path(tmp) / "scenario.json"
        opts.scenario.save(scenario_file)
        world_out = open(Path(tmp) / "world.json", "w+b")
        files.append(world_out)
        try:
            world = spawn("world", world_command(opts, scenario_file, label), env, world_out, output("world"))
            children.append(world)
            recorder = None
            if opts.record:
                recorder = spawn("recorder", recorder_command(opts, team), env, output("recorder"), subprocess.STDOUT)
                children.append(recorder)
            drivers = [spawn(name, args, env, output(name), subprocess.STDOUT)
                       for name, args in driver_commands(opts, team).items()]
            children.extend(drivers)
            _wait_for_world(world, recorder, drivers, opts.timeout_s)
            if world.process.returncode != 0:
                raise RuntimeError(f"the world exited with status {world.process.returncode}")
            world_out.seek(0)
            summary = json.loads(world_out.read().decode().strip().splitlines()[-1])
            leave_by = time.monotonic() + HOST_EXIT_S  # --once drivers leave when they see the end
            for child in drivers:
                try:
                    child.process.wait(timeout=max(0.0, leave_by - time.monotonic()))
                except subprocess.TimeoutExpired:
                    pass
        finally:
            codes = {child.name: child.stop(RECORDER_GRACE_S if child.name == "recorder" else STOP_GRACE_S)
                     for child in reversed(children)}
            for file in files:
                file.close()
    summary.update(hosts=len(drivers), transport=opts.transport, external=list(opts.external),
                   launch_wall_s=time.monotonic() - started, exit_codes=codes)
    if opts.record:
        summary["recording"] = opts.record
    return summary
