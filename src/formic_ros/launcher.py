"""``formic run``: the world, the agent hosts (or the planner) and optionally the recorder as
separate ROS processes, one episode, a summary, and nothing left behind.

Each child runs ``python -m formic_cli.main <command>`` in a session of its own (so a terminal's
Ctrl-C reaches only the launcher, which then stops the children in order) and with a parent-death
signal (so even a SIGKILLed launcher leaves no orphans). Stopping is SIGINT, then SIGTERM, then
SIGKILL to the child's whole process group, each after a grace period, and every child is
reaped. The world waits for every agent before step 0 (discovery; with ``--record`` also for
the recorder's subscriptions), plays the episode and prints its summary as one JSON line,
which the launcher reads from the world's stdout.

``formic train-ros`` (:func:`launch_training`) starts distributed training the same way: the
trainer node, the world in training mode and one learning host.
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
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

from formic_runtime.registry import DEFAULT_MODEL, apply_world_overrides
from formic_runtime.team import Team
from formic_world import Scenario

from . import qos
from .env import check_domain_id, ros_environment

if TYPE_CHECKING:
    from formic_trainer.config import TrainConfig

STOP_GRACE_S = (5.0, 3.0)  # after SIGINT, after SIGTERM; then SIGKILL
RECORDER_GRACE_S = (20.0, 5.0)  # the recorder closes its file on SIGINT
DEFAULT_MAX_LAG = 4  # the trainer node's (formic_ros.trainer_node imports torch)
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
    view_port: int | None = None  # the world serves a live view (formic_view) on this port


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
    if opts.view_port is not None:
        args += ["--view", "--view-port", str(opts.view_port)]
    return args


def recorder_command(opts: RunOptions, team: Team) -> list[str]:
    args = ["record", "--out", opts.record, "--namespace", opts.namespace]
    if "formic" in team.names:
        args += ["--model", str(opts.model or DEFAULT_MODEL)]
    return args


def driver_commands(opts: RunOptions, team: Team) -> dict[str, list[str]]:
    """The processes that answer the world: the planner node, or the agent hosts."""
    if "planner" in team.names:
        return {"planner": ["planner", "--namespace", opts.namespace, "--once"]}
    commands = {}
    for i, ids in enumerate(team.split(opts.hosts)):
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



def child_output(log_dir, name: str, files: list):
    """Where a child process writes: stderr, or ``LOG_DIR/NAME.log`` (kept in ``files`` to close)."""
    if log_dir is None:
        return sys.stderr
    Path(log_dir).mkdir(parents=True, exist_ok=True)
    files.append(open(Path(log_dir) / f"{name}.log", "w"))
    return files[-1]

def launch(opts: RunOptions) -> dict:
    """Play one episode across processes; returns the world's summary (plus launch details).
    Raises RuntimeError when the world fails; children are stopped and reaped in any case."""
    team = Team.parse(opts.policy, opts.scenario.config.n_agents, external=opts.external)
    # The world the team needs (one-slot queues for csaf-ref): the world node serves, and the
    # recorder records, this scenario, so a replay re-simulates the same world.
    scenario = apply_world_overrides(opts.scenario, team.names)
    if "planner" in team.names and opts.external:
        raise ValueError("the planner commands every agent; it cannot leave some to --external")
    check_domain_id(opts.domain_id)
    env = ros_environment(opts.domain_id)
    label = opts.policy + (f",external:{ids_text(list(opts.external))}" if opts.external else "")
    children: list[Child] = []
    files = []  # output files, closed at the end
    started = time.monotonic()
    with tempfile.TemporaryDirectory(prefix="formic-run-") as tmp:

        def output(name: str):
            return child_output(opts.log_dir, name, files)

        scenario_file = Path(tmp) / "scenario.json"
        scenario.save(scenario_file)
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


# ----------------------------------------------------------------------------- training
EPISODE_FIELDS = ("episode", "food", "seed", "size", "highway_intensity", "deposit_strength", "missed_actions",
                  "rejected_actions", "steps_per_s", "state_digest")  # of each episode's summary, kept
TRAINING_DEADLINE_MS = 120_000.0  # a lockstep step may wait this long for an update (and the trainer for the last)


@dataclass
class TrainRunOptions:
    config: TrainConfig
    run_dir: str
    episodes: int
    fresh: bool = False
    switch: str = "chunk"  # when hosts take new weights: after each rollout (on-policy), or per episode
    namespace: str = qos.DEFAULT_NAMESPACE
    domain_id: int | None = None
    deadline_ms: float = TRAINING_DEADLINE_MS
    startup_timeout_s: float = 120.0
    viewer_every: int = 0
    log_dir: str | None = None
    timeout_s: float | None = None
    on_episode: Callable[[dict], None] | None = None  # gets each episode's summary as it ends


def first_episode(run_dir: str, fresh: bool) -> int:
    """The global episode a run continues from (what the trainer node resumes to)."""
    latest = Path(run_dir) / "latest.pt"
    if fresh or not latest.exists():
        return 0
    from formic_agent.checkpoint import read_checkpoint

    return int(read_checkpoint(latest)["progress"]["episode"])


def training_commands(opts: TrainRunOptions, config_file: Path, start: int) -> dict[str, list[str]]:
    """World (training mode), one learning host (batched, the whole team) and the trainer."""
    common = ["--namespace", opts.namespace, "--train-config", str(config_file)]
    chunks = math.ceil(opts.config.episode_steps / opts.config.rollout_steps)
    trainer = ["trainer", *common, "--run-dir", opts.run_dir, "--max-rollouts", str(opts.episodes * chunks),
               "--max-lag", str(max(DEFAULT_MAX_LAG, chunks)), "--json"]
    if opts.fresh:
        trainer.append("--fresh")
    return {
        "trainer": trainer,
        "world": ["world", *common, "--episodes", str(opts.episodes), "--first-episode", str(start),
                  "--deadline-ms", str(opts.deadline_ms), "--startup-timeout", str(opts.startup_timeout_s),
                  "--viewer-every", str(opts.viewer_every), "--json"],
        "host0": ["agents", *common, "--ids", f"0-{opts.config.teams[0] - 1}", "--transport", "batched",
                  "--switch-weights", opts.switch, "--episodes", str(opts.episodes), "--first-episode", str(start),
                  "--name", "agent_host_0"],
    }


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


def launch_training(opts: TrainRunOptions) -> dict:
    """Distributed training: the trainer node, the world (``opts.episodes`` training episodes)
    and one learning host as separate processes, on the in-process trainer's settings
    (``opts.config``) and scenario stream; resumes ``run_dir`` unless ``fresh``. Returns each
    episode's summary (the learning curve: ``EPISODE_FIELDS``) and the trainer's result;
    children are stopped and reaped in any case."""
    from .training_world import require_one_world

    cfg = opts.config
    require_one_world(cfg)
    check_domain_id(opts.domain_id)
    env = ros_environment(opts.domain_id)
    start = first_episode(opts.run_dir, opts.fresh)
    children: list[Child] = []
    files = []
    started = time.monotonic()
    with tempfile.TemporaryDirectory(prefix="formic-train-") as tmp:

        def output(name: str):
            return child_output(opts.log_dir, name, files)

        config_file = Path(tmp) / "train_config.json"
        config_file.write_text(json.dumps(cfg.to_dict()))
        outs = {name: open(Path(tmp) / f"{name}.json", "w+b") for name in ("trainer", "world")}
        files.extend(outs.values())
        commands = training_commands(opts, config_file, start)
        episodes: list[dict] = []
        world_lines = JsonLines(outs["world"])

        def collect_episodes() -> None:
            for summary in world_lines.new():
                episodes.append({key: summary[key] for key in EPISODE_FIELDS})
                if opts.on_episode is not None:
                    opts.on_episode(summary)

        try:
            for name, args in commands.items():
                stdout = outs.get(name) or output(name)
                children.append(spawn(name, args, env, stdout, output(name) if name in outs else subprocess.STDOUT))
            trainer, world, host = children
            deadline = None if opts.timeout_s is None else time.monotonic() + opts.timeout_s
            while world.alive:
                for child in (trainer, host):
                    if child.process.poll():
                        raise RuntimeError(f"{child.name} failed with status {child.process.returncode} (see its log)")
                if deadline is not None and time.monotonic() > deadline:
                    raise RuntimeError(f"training did not finish within {opts.timeout_s} s")
                collect_episodes()
                try:
                    world.process.wait(timeout=0.5)
                except subprocess.TimeoutExpired:
                    pass
            if world.process.returncode != 0:
                raise RuntimeError(f"the world exited with status {world.process.returncode}")
            collect_episodes()
            try:  # the trainer leaves by itself after the last rollout's update
                trainer.process.wait(timeout=opts.deadline_ms / 1e3)
            except subprocess.TimeoutExpired:
                raise RuntimeError(f"the trainer did not finish its last update within {opts.deadline_ms / 1e3:g} s") from None
            if trainer.process.returncode != 0:
                raise RuntimeError(f"the trainer exited with status {trainer.process.returncode}")
            result = JsonLines(outs["trainer"]).new()[-1]
            try:
                host.process.wait(timeout=HOST_EXIT_S)
            except subprocess.TimeoutExpired:
                pass
        finally:
            codes = {child.name: child.stop() for child in reversed(children)}
            for file in files:
                file.close()
    return {"run_dir": opts.run_dir, "first_episode": start, "episodes": episodes, "trainer": result,
            "launch_wall_s": time.monotonic() - started, "exit_codes": codes}
