"""``formic run``: the world, the agent hosts (or the planner) and optionally the recorder as
separate ROS processes, one episode, a summary, and nothing left behind.

The launcher builds the run (:class:`RunOptions` -> one node spec per child, the options of the
very ``serve_*`` function the child calls, see :mod:`formic_ros.launch.node_process`) and starts and
stops the children (:mod:`formic_ros.launch.processes`: own session, parent-death signal, SIGINT, then
SIGTERM, then SIGKILL, every child reaped). The world waits for every agent before step 0
(discovery; with ``--record`` also for the recorder's subscriptions), plays the episode and
prints its summary as one JSON line, which the launcher reads from the world's stdout.

``formic train-ros`` (:func:`launch_training`) starts distributed training the same way: the
trainer node, the world in training mode and one learning host.
"""

from __future__ import annotations

import json
import math
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import TYPE_CHECKING

from formic_runtime.registry import DEFAULT_MODEL, apply_world_overrides, model_path
from formic_runtime.team import Team
import formic_topics as topics
from formic_world import Scenario

from ..drivers.lag import DEFAULT_MAX_LAG
from ..env import check_domain_id, ros_environment, warn_if_exposed
from ..world.lock import check_world_free
from ..world.options import WorldNodeOptions
from .node_process import node_spec
from .processes import RECORDER_GRACE_S, Children, JsonLines, watch

if TYPE_CHECKING:
    from formic_trainer.config import TrainConfig

    from .robots import RobotRunOptions

HOST_EXIT_S = 10.0  # how long hosts get to leave by themselves after the episode


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
    namespace: str = topics.DEFAULT_NAMESPACE
    domain_id: int | None = None
    deadline_ms: float = 1000.0
    startup_timeout_s: float = 60.0
    rate_hz: float | None = None
    viewer_every: int = 10
    progress: bool = False
    log_dir: str | None = None  # children's output there (one file each) instead of stderr
    timeout_s: float | None = None  # give up on the world after this long
    view_port: int | None = None  # the world serves a live view (formic_view) on this port
    view_wait: bool = False  # step 0 waits for a viewer to subscribe to it
    robots: RobotRunOptions | None = None  # robot agents: their bridges (and simulator), docs/robots.md


def world_spec(opts: RunOptions, scenario_file: Path, label: str, drivers: list[str]) -> dict:
    options = WorldNodeOptions(  # a recorder must have matched every topic before step 0
        namespace=opts.namespace, deadline_s=opts.deadline_ms / 1e3, startup_timeout_s=opts.startup_timeout_s,
        rate_hz=opts.rate_hz or None, viewer_every=opts.viewer_every, policy_label=label,
        recorders=1 if opts.record else 0, progress=opts.progress, view_port=opts.view_port,
        view_wait=opts.view_wait,
        external=tuple(opts.external), drivers=tuple(topics.full_name(opts.namespace, name) for name in drivers),
        **(opts.robots.world_fields() if opts.robots else {}),
    )
    return node_spec("world", scenario=str(scenario_file), options=asdict(options), domain_id=opts.domain_id)


def recorder_spec(opts: RunOptions, team: Team) -> dict:
    model = str(opts.model or DEFAULT_MODEL) if "formic" in team.names else None
    return node_spec("recorder", out=opts.record, model=model, namespace=opts.namespace, domain_id=opts.domain_id)


def driver_specs(opts: RunOptions, team: Team) -> dict[str, dict]:
    """The processes that answer the world: the planner node, or the agent hosts (and the robot
    bridges, with the robot simulator, deciding for and driving the robot agents)."""
    if "planner" in team.names:
        return {"planner": node_spec("planner", namespace=opts.namespace, once=True, domain_id=opts.domain_id)}
    robots = set(opts.robots.agents) if opts.robots else set()
    hosts = [[int(a) for a in ids if a not in robots] for ids in team.split(opts.hosts)]
    specs = {f"host{i}": node_spec("agents", agent_ids=ids, spec=opts.policy, once=True,
                                   domain_id=opts.domain_id, model=opts.model, greedy=opts.greedy,
                                   transport=opts.transport, namespace=opts.namespace, name=f"agent_host_{i}")
             for i, ids in enumerate(hosts) if ids}
    if opts.robots:
        from .robots import robot_specs

        specs |= robot_specs(opts.robots, team, opts.policy, opts.namespace, opts.domain_id, opts.model, opts.greedy)
    return specs


def launch(opts: RunOptions) -> dict:
    """Play one episode across processes; returns the world's summary (plus launch details).
    Raises RuntimeError when the world fails; children are stopped and reaped in any case."""
    team = Team.parse(opts.policy, opts.scenario.config.n_agents, external=opts.external)
    if opts.robots:
        from .robots import check_robots

        check_robots(opts.robots, team, opts.scenario.config.n_agents)
    # The world the team needs (one-slot queues for csaf-ref): the world node serves, and the
    # recorder records, this scenario, so a replay re-simulates the same world.
    scenario = apply_world_overrides(opts.scenario, team.names)
    if "formic" in team.names:
        model_path(opts.model)  # a missing model: an error here, before any process starts
    if "planner" in team.names and opts.external:
        raise ValueError("the planner commands every agent; it cannot leave some to --external")
    check_domain_id(opts.domain_id)
    check_world_free(opts.namespace, opts.domain_id)
    label = opts.policy + (f",external:{','.join(map(str, opts.external))}" if opts.external else "")
    started = time.monotonic()
    warn_if_exposed()
    with Children("formic-run-", ros_environment(opts.domain_id), opts.log_dir) as run:
        scenario_file = run.dir / "scenario.json"
        scenario.save(scenario_file)
        world_out = run.stdout("world")
        specs = driver_specs(opts, team)
        driver_nodes = [spec["kwargs"].get("name", spec["node"]) for spec in specs.values()]  # the planner: "planner"
        world = run.start("world", world_spec(opts, scenario_file, label, driver_nodes), world_out)
        recorder = run.start("recorder", recorder_spec(opts, team), grace_s=RECORDER_GRACE_S) if opts.record else None
        drivers = [run.start(name, spec) for name, spec in specs.items()]
        # the recorder leaving, or a host or the planner failing, before the world ends is an error
        watch(world, drivers, opts.timeout_s, "the world", required=recorder)
        summary = JsonLines(world_out).new()[-1]
        leave_by = time.monotonic() + HOST_EXIT_S  # --once drivers leave when they see the end
        for child in drivers:
            child.wait(leave_by - time.monotonic())
    summary.update(hosts=len(drivers), transport=opts.transport, external=list(opts.external),
                   launch_wall_s=time.monotonic() - started, exit_codes=run.codes)
    if opts.record:
        summary["recording"] = opts.record
    return summary


# ----------------------------------------------------------------------------- training
EPISODE_FIELDS = ("episode", "food", "seed", "size", "highway_intensity", "deposit_strength", "missed_actions",
                  "rejected_actions", "steps_per_s", "state_digest")  # of each episode's summary, kept
LEARNING_HOST = "agent_host_0"  # the node name of train-ros's one learning host (the world's only driver)
TRAINING_DEADLINE_MS = 120_000.0  # a lockstep step may wait this long for an update (and the trainer for the last)


@dataclass
class TrainRunOptions:
    config: TrainConfig
    run_dir: str
    episodes: int
    fresh: bool = False
    switch: str = "chunk"  # when hosts take new weights: after each rollout (on-policy), or per episode
    namespace: str = topics.DEFAULT_NAMESPACE
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


def training_specs(opts: TrainRunOptions, config_file: Path, start: int) -> dict[str, dict]:
    """Trainer, world (training mode) and one learning host (batched, the whole team)."""
    common = {"train_config": str(config_file), "namespace": opts.namespace, "domain_id": opts.domain_id}
    chunks = math.ceil(opts.config.episode_steps / opts.config.rollout_steps)
    world = WorldNodeOptions(namespace=opts.namespace, deadline_s=opts.deadline_ms / 1e3,
                             startup_timeout_s=opts.startup_timeout_s, viewer_every=opts.viewer_every,
                             external=(), drivers=(topics.full_name(opts.namespace, LEARNING_HOST),))
    return {
        "trainer": node_spec("trainer", **common, run_dir=opts.run_dir, resume=not opts.fresh,
                             max_rollouts=opts.episodes * chunks, max_lag=max(DEFAULT_MAX_LAG, chunks)),
        "world": node_spec("world", train_config=str(config_file), episodes=opts.episodes,
                           first_episode=start, options=asdict(world), domain_id=opts.domain_id),
        "host0": node_spec("learning_agents", **common, agent_ids=list(range(opts.config.teams[0])),
                           switch=opts.switch, episodes=opts.episodes, first_episode=start, name=LEARNING_HOST),
    }


def launch_training(opts: TrainRunOptions) -> dict:
    """Distributed training: the trainer node, the world (``opts.episodes`` training episodes)
    and one learning host as separate processes, on the in-process trainer's settings
    (``opts.config``) and scenario stream; resumes ``run_dir`` unless ``fresh``. Returns each
    episode's summary (the learning curve: ``EPISODE_FIELDS``) and the trainer's result;
    children are stopped and reaped in any case."""
    from ..world.training import require_one_world

    cfg = opts.config
    require_one_world(cfg)
    check_domain_id(opts.domain_id)
    check_world_free(opts.namespace, opts.domain_id)
    start = first_episode(opts.run_dir, opts.fresh)
    started = time.monotonic()
    warn_if_exposed()
    with Children("formic-train-", ros_environment(opts.domain_id), opts.log_dir) as run:
        config_file = run.dir / "train_config.json"
        config_file.write_text(json.dumps(cfg.to_dict()))
        outs = {name: run.stdout(name) for name in ("trainer", "world")}
        episodes: list[dict] = []
        world_lines = JsonLines(outs["world"])

        def collect_episodes() -> None:
            for summary in world_lines.new():
                episodes.append({key: summary[key] for key in EPISODE_FIELDS})
                if opts.on_episode is not None:
                    opts.on_episode(summary)

        trainer, world, host = (run.start(name, spec, outs.get(name))
                                for name, spec in training_specs(opts, config_file, start).items())
        watch(world, [trainer, host], opts.timeout_s, "training", poll_s=0.5, tick=collect_episodes)
        collect_episodes()
        trainer.wait(opts.deadline_ms / 1e3)  # the trainer leaves by itself after the last rollout's update
        if trainer.alive:
            raise RuntimeError(f"the trainer did not finish its last update within {opts.deadline_ms / 1e3:g} s")
        if trainer.process.returncode != 0:
            raise RuntimeError(trainer.error())
        result = JsonLines(outs["trainer"]).new()[-1]
        host.wait(HOST_EXIT_S)
    return {"run_dir": opts.run_dir, "first_episode": start, "episodes": episodes, "trainer": result,
            "launch_wall_s": time.monotonic() - started, "exit_codes": run.codes}
