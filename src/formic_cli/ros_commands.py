"""ROS commands: ``formic run`` (the whole system), ``formic world | agents | planner`` (one node
each, for running nodes on several machines) and ``formic bench ros``. Registered by
``formic_cli.main`` when this module imports (it needs rclpy and formic_interfaces only
inside the commands)."""

from __future__ import annotations

import os
import sys
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import click

from formic_world.limits import MAX_EPISODE_STEPS

from .options import (COUNT, POSITIVE, SIDE, TEAM, WORLD_OPTION_NAMES, OutputFolder, comma_list,
                      domain_option, fresh_option, greedy_option, hosts_network_option, json_option, live_view_port,
                      map_origin_options, model_option, option_group, preset_option, ros_node_name, ros_options, ros_run_dir_option,
                      scenario_from, stored_train_config, team_options, train_config_option, training_config,
                      view_options, world_options)
from .robot_commands import (robot, robot_run_options, robots_sim, run_robot_options, scenarios_starts,
                             world_robot_options)
from .summary import click_errors, emit, emit_json, print_episode_summary

TRANSPORT = click.Choice(["per-agent", "batched"])
SWITCH = click.Choice(["chunk", "episode", "newest"])


def lockstep_options(deadline_ms: float = 1000.0,
                     deadline_help: str = "Lockstep: how long a step waits for the last action.",
                     startup_timeout: float = 60.0, viewer_every: int = 10, rate: bool = True):
    """The world's --namespace --domain-id --deadline-ms --startup-timeout --rate --viewer-every (named
    as RunOptions' fields); ``rate=False`` leaves --rate out."""
    rate_option = click.option("--rate", "rate_hz", type=POSITIVE,
                               help="Free-running: steps per second, not waiting for agents.")
    return option_group(
        ros_options(),
        click.option("--deadline-ms", type=POSITIVE, default=deadline_ms, show_default=True, help=deadline_help),
        click.option("--startup-timeout", "startup_timeout_s", type=POSITIVE, default=startup_timeout,
                     show_default=True, help="Seconds step 0 waits for every agent."),
        *([rate_option] if rate else []),
        click.option("--viewer-every", type=click.IntRange(min=0), default=viewer_every, show_default=True,
                     help="Publish map and markers every k steps (0: never)."),
    )


# --log-dir --timeout of the commands that launch processes (named as RunOptions' fields)
launch_options = option_group(
    click.option("--log-dir", type=OutputFolder(), help="Write each process's log here instead of stderr."),
    click.option("--timeout", "timeout_s", type=POSITIVE, help="Give up after this many seconds."),
)


def _counts(counts: dict) -> str:
    return ", ".join(f"{k} {v}" for k, v in counts.items()) if counts else "0"


def _print_ros_summary(summary: dict) -> None:
    print_episode_summary(summary)
    click.echo(
        f"ROS: {summary['mode']}, {summary['steps_per_s']:.0f} steps/s after a {summary['startup_s']:.1f} s start; "
        f"missed actions {summary['missed_actions']}; rejected actions {_counts(summary.get('rejected_actions', {}))}"
    )
    if "robots" in summary:  # the world's robot figures (docs/robots.md)
        click.echo(f"robots {summary['robots']}: a step took {summary['robot_step_s_mean']:.2f} s on average, "
                   f"{summary['robot_step_s_max']:.2f} s at most; failed moves {summary['robot_failed_moves']}; "
                   f"rejected statuses {_counts(summary.get('rejected_statuses', {}))}")
    click.echo(f"state digest {summary['state_digest']}")


def _print_training_episode(summary: dict) -> None:
    h, w = summary["size"]
    click.echo(f"ep {summary['episode']:6d} | food {summary['food']:6.1f} | {h}x{w}, seed {summary['seed']} | "
               f"I_h {summary['highway_intensity']:.2f} | missed actions {summary['missed_actions']}")


def _parse_external(text: str | None) -> tuple[int, ...]:
    from formic_runtime.team import parse_ids

    try:
        return tuple(parse_ids(text)) if text else ()
    except ValueError as exc:
        raise click.BadParameter(str(exc), param_hint="'--external'") from exc


@click.command()
@hosts_network_option
@world_options
@team_options
@click.option("--hosts", type=COUNT, default=1, show_default=True,
              help="Agent host processes to split the team over (at most one an agent).")
@click.option("--transport", type=TRANSPORT, default="per-agent", show_default=True,
              help="One node and topic pair per agent, or one batched topic pair per host.")
@click.option("--external", help="Agents driven by your own node on their per-agent topics, e.g. 5 or 0-3.")
@click.option("--record", type=OutputFolder(), help="Record every topic to this rosbag2 (MCAP) directory.")
@click.option("--timeline", type=OutputFolder(),
              help="Note when each step's messages leave and arrive in every process, into this (fresh) folder, "
                   "and report where a step's time went (formic timeline).")
@lockstep_options()
@launch_options
@view_options()
@run_robot_options
@json_option()
def run(scenario_file, external, live_view, view_port, view_wait, as_json, timeline, **fields) -> None:
    """The main job: world, agent hosts (or the planner) and recorder as separate ROS processes."""
    from formic_ros.launch.launcher import RunOptions, launch

    if timeline is not None and fields["policy"].strip() == "planner":
        raise click.UsageError("--timeline times agent hosts; the centralized planner runs without one")
    robots = robot_run_options(fields)  # --robots and the rest (docs/robots.md)
    scenario = scenario_from(scenario_file, fields)  # takes the world options out: RunOptions' fields remain
    if fields["hosts"] > scenario.config.n_agents:
        raise click.BadParameter(f"{fields['hosts']} hosts for {scenario.config.n_agents} agents: at most one an agent",
                                 param_hint="'--hosts'")
    options = RunOptions(scenario=scenario, external=_parse_external(external), robots=robots, **fields,
                         progress=not as_json and sys.stderr.isatty(),
                         view_port=live_view_port(live_view, view_port, view_wait), view_wait=view_wait)
    if live_view:  # served by the world process (formic_view), announced here where the user looks
        from formic_view import DEFAULT_HOST, address, announcement

        click.echo(announcement(address(DEFAULT_HOST, view_port)) if view_port else
                   "live view: on a free port the world process picks (its log's 'live view:' line names it)", err=True)
    with click_errors(RuntimeError, ValueError, FileNotFoundError,
                      interrupted="interrupted: every process stopped"), _timeline_for_children(timeline):
        summary = launch(options)
        if timeline is not None:
            from formic_ros.timeline import segments

            summary["timeline"] = segments(timeline)
    if as_json:
        emit_json(summary)
        return
    _print_ros_summary(summary)
    click.echo(f"{summary['hosts']} host process(es), {summary['transport']} transport"
               + (f"; recording in {summary['recording']}" if "recording" in summary else ""))
    if timeline is not None:
        _print_timeline(summary["timeline"])


@contextmanager
def _timeline_for_children(folder: str | None) -> Iterator[None]:
    """``FORMIC_TIMELINE`` in the environment the run's processes inherit, while they run, into
    a folder without another run's timeline (no folder: nothing changes)."""
    from formic_ros.timeline import ENV

    if folder is None:
        yield
        return
    if any(Path(folder).glob("world-*.csv")) or any(Path(folder).glob("host-*.csv")):
        raise click.BadParameter(f"{folder} already holds a run's timeline: give each run a fresh folder",
                                 param_hint="'--timeline'")
    previous = os.environ.get(ENV)
    os.environ[ENV] = str(Path(folder).resolve())
    try:
        yield
    finally:
        if previous is None:
            del os.environ[ENV]
        else:
            os.environ[ENV] = previous


def _print_timeline(report: dict) -> None:
    parts = report["segments_ms"]
    click.echo(f"where a step's time went (medians over {report['steps']} steps, {report['hosts']} host(s); "
               f"a step took {report['cycle_ms']:.2f} ms, the parts add up to {sum(parts.values()):.2f} ms):")
    for label, ms in parts.items():
        click.echo(f"  {label:<64}{ms:8.3f} ms")


@click.command("timeline")
@click.argument("folder", type=click.Path(exists=True, file_okay=False))
@json_option()
def timeline_report(folder, as_json) -> None:
    """Where a step's time went in a run with FORMIC_TIMELINE=FOLDER (or formic run --timeline)."""
    from formic_ros.timeline import segments

    with click_errors(ValueError):
        report = segments(folder)
    emit(as_json, report, _print_timeline)


@click.command()
@hosts_network_option
@world_options
@click.option("--scenario", "scenario_file", type=click.Path(exists=True, dir_okay=False),
              help="Serve a stored scenario (its configuration wins over world options).")
@click.option("--policy-label", default="", help="Which policies drive the team (recorded in the scenario message).")
@lockstep_options()
@click.option("--dt", type=POSITIVE, default=0.1, show_default=True, help="Simulated seconds per step (/clock).")
@click.option("--training-masks", is_flag=True, help="Fill the training-filter masks of ObservationBatch.")
@click.option("--observation-encoding", type=click.Choice(["compact", "float32"]), default="compact",
              show_default=True,
              help="How ObservationBatch carries observations: compact (lossless, ~10x smaller) or plain float32.")
@click.option("--require-subscriber", "require_subscribers", multiple=True,
              type=click.Choice(["state", "applied_actions", "observations", "summary", "scenario", "score"]),
              help="Do not start before this topic has a subscriber (e.g. a recorder); repeatable.")
@click.option("--recorders", type=click.IntRange(min=0), default=0, show_default=True,
              help="Do not step before this many recorders (`formic record`) have matched every topic; "
                   "recorders already running when the world starts are waited for anyway.")
@click.option("--stay", is_flag=True, help="Keep serving the latched scenario and summary after the episode.")
@click.option("--paused", is_flag=True,
              help="Start paused at step 0 for a simulation_interfaces client (play, step, reset: docs/ros.md) "
                   "and stay up until it sets STATE_QUITTING.")
@click.option("--cell-size", type=POSITIVE, default=1.0, show_default=True,
              help="Metres per cell in the map frame of the entity poses (simulation_interfaces).")
@map_origin_options
@click.option("--allow-empty", is_flag=True,
              help="Step through the episode even when agents do not answer step 0 (default: exit with an error "
                   "naming them).")
@click.option("--train-config", type=click.Path(exists=True, dir_okay=False),
              help="Training mode: play --episodes episodes on scenarios drawn as `formic train` draws them "
                   "for this training configuration (a run directory's config.json); world options are ignored.")
@click.option("--episodes", type=COUNT, default=1, show_default=True, help="Training mode: episodes to play.")
@click.option("--first-episode", type=click.IntRange(min=0), default=0, show_default=True,
              help="Training mode: global episode to start from (a resumed run's).")
@click.option("--progress", is_flag=True, help="Show a progress bar on stderr.")
@world_robot_options
@view_options()
@json_option(help="Print the summary as one JSON line.")
def world(scenario_file, domain_id, deadline_ms, stay, train_config, episodes, first_episode, live_view, view_port,
          view_wait, as_json, **fields) -> None:
    """The world node: owns the simulation and steps it with the agents over ROS."""
    from formic_ros.errors import RunError
    from formic_ros.world.options import WorldNodeOptions
    from formic_ros.world.serve import serve_world
    from formic_ros.world.training import require_one_world, serve_training_world

    world_kw = {name: fields.pop(name) for name in WORLD_OPTION_NAMES}  # the rest are WorldNodeOptions'
    options = WorldNodeOptions(deadline_s=deadline_ms / 1e3, view_port=live_view_port(live_view, view_port, view_wait),
                               view_wait=view_wait, **fields)
    if train_config:
        cfg = stored_train_config(train_config)
        with click_errors(ValueError, prefix=f"{train_config}: "):
            require_one_world(cfg)
    with click_errors(RunError, interrupted=""):
        if train_config:
            serve_training_world(cfg, episodes, options, first_episode=first_episode, domain_id=domain_id,
                                 on_episode=emit_json if as_json else _print_training_episode)
        else:
            serve_world(scenario_from(scenario_file, world_kw), options, domain_id=domain_id,
                        on_summary=emit_json if as_json else _print_ros_summary, stay=stay,
                        scenario_file=scenario_file or "")


@click.command()
@hosts_network_option
@click.option("--ids", required=True, help="Agents this host drives, e.g. 0-31 or 0-3,8-11.")
@click.option("--policy", default="formic", show_default=True,
              help="Policy, or a team spec with global ids such as formic:0-15,csaf11:16-31.")
@model_option
@greedy_option
@click.option("--transport", type=TRANSPORT, default="per-agent", show_default=True)
@ros_options()
@click.option("--name", callback=ros_node_name, help="Node name of the host (default agent_host_<pid>).")
@click.option("--threads", type=COUNT, default=1, show_default=True, help="Torch threads for learned agents.")
@click.option("--once", is_flag=True, help="Exit when the episode ends (default: serve episode after episode).")
@click.option("--train-config", type=click.Path(exists=True, dir_okay=False),
              help="Learning mode (batched transport): the agents act and send rollouts for the trainer node "
                   "under this training configuration (a run directory's config.json); --policy is ignored.")
@click.option("--switch-weights", type=SWITCH, default="chunk", show_default=True,
              help="Learning mode: wait for each rollout's update and act on with it (as `formic train`), "
                   "wait at each episode start for the updates of its rollouts, or never wait and take the "
                   "newest weights at each chunk start (asynchronous).")
@click.option("--episodes", type=COUNT, help="Learning mode: exit after this many episodes.")
@click.option("--first-episode", type=click.IntRange(min=0), default=0, show_default=True,
              help="Learning mode: global episode number of the first episode (a resumed run's).")
def agents(ids, policy, model, greedy, transport, namespace, domain_id, name, threads, once, train_config,
           switch_weights, episodes, first_episode) -> None:
    """An agent host: many agents (each its own node by default) in one process."""
    from formic_ros.drivers.agent_host import serve_agents
    from formic_ros.errors import WorldLost
    from formic_runtime.team import parse_ids

    try:
        agent_ids = parse_ids(ids)
    except ValueError as exc:
        raise click.BadParameter(str(exc), param_hint="'--ids'") from exc
    with click_errors(ValueError, FileNotFoundError, WorldLost, interrupted=""):
        if train_config:
            from formic_ros.drivers.learning_host import serve_learning_agents

            if transport != "batched":
                raise click.UsageError("learning mode (--train-config) needs --transport batched")
            serve_learning_agents(agent_ids, stored_train_config(train_config), switch=switch_weights,
                                  first_episode=first_episode, namespace=namespace, name=name,
                                  episodes=1 if once else episodes, domain_id=domain_id, threads=threads)
            return
        serve_agents(agent_ids, policy, model=model, greedy=greedy, transport=transport, namespace=namespace,
                     name=name, once=once, domain_id=domain_id, threads=threads)


@click.command("train-ros")
@hosts_network_option
@preset_option
@train_config_option
@click.option("--set", "overrides", multiple=True, metavar="KEY=VALUE",
              help="Override a training field (one world: --set teams=N).")
@ros_run_dir_option
@click.option("--episodes", type=COUNT, required=True, help="Environment episodes to add in this call.")
@fresh_option
@click.option("--switch-weights", "switch", type=SWITCH, default="chunk", show_default=True,
              help="Hosts wait for each rollout's update (as `formic train`), take new weights per episode, or "
                   "take the newest at each chunk without waiting (with --actors: asynchronous updates).")
@click.option("--actors", type=click.IntRange(min=1), default=1, show_default=True,
              help="Actors (a world and its learning host each), one per world of the config; >1: docs/ros.md.")
@lockstep_options(deadline_ms=120000.0, startup_timeout=120.0, viewer_every=0, rate=False,
                  deadline_help="Lockstep deadline; a step can wait for an update, so it is long.")
@launch_options
@json_option(help="Print one JSON object at the end.")
def train_ros(preset, train_config, overrides, as_json, actors, **options) -> None:
    """Distributed training: trainer node, world (training scenarios) and a learning host as
    separate ROS processes; same settings and seeds give `formic train`'s learning curve."""
    from formic_ros.launch.launcher import TrainRunOptions, launch_training
    from formic_trainer.config import require_distributable

    with click_errors(RuntimeError, ValueError, TypeError, FileNotFoundError,
                      interrupted="interrupted: every process stopped (the trainer saved its checkpoint)"):
        cfg = training_config(preset, train_config, overrides)
        require_distributable(cfg)
        run_options = TrainRunOptions(config=cfg, **options, on_episode=None if as_json else _print_training_episode)
        if actors > 1:
            from formic_ros.launch.actors import launch_actors_training

            result = launch_actors_training(run_options, actors)
        else:
            result = launch_training(run_options)
    trainer = result["trainer"]
    emit(as_json, result, f"trained {len(result['episodes'])} episodes from episode "
         f"{result['first_episode']}: weights version {trainer['version']} ({trainer['dropped']} rollouts "
         f"dropped); checkpoint in {options['run_dir']}/latest.pt")


@click.command()
@hosts_network_option
@ros_options()
@click.option("--once", is_flag=True, help="Exit when the episode ends.")
def planner(namespace, domain_id, once) -> None:
    """The centralized planner node: reads the full state, commands every agent."""
    from formic_ros.drivers.planner import serve_planner
    from formic_ros.errors import WorldLost

    with click_errors(WorldLost, interrupted=""):
        mismatches = serve_planner(namespace, once=once, domain_id=domain_id)
    if mismatches:
        raise click.ClickException(f"the planner's replica differed from the world {mismatches} time(s)")


@click.command("ros")
@click.option("--agents", "teams", default="16,64,128", show_default=True, help="Team sizes, comma list.")
@click.option("--transports", default="batched,per-agent", show_default=True, help="Comma list.")
@click.option("--steps", type=click.IntRange(2, MAX_EPISODE_STEPS), default=300, show_default=True,
              help="Lockstep steps per measurement (step 0, start-up and discovery, is not timed).")
@click.option("--size", type=SIDE, default=64, show_default=True, help="World side.")
@click.option("--repeats", type=click.IntRange(min=1), default=1, show_default=True,
              help="Launches per setting (the best is kept).")
@domain_option()
@json_option(help=None)
def bench_ros(teams, transports, steps, size, repeats, domain_id, as_json) -> None:
    """Lockstep steps/s of world + one host process over ROS, random policy (messaging cost)."""
    from formic_ros.launch.bench import bench_ros as measure

    results = []
    for transport in comma_list(transports, str, "--transports", TRANSPORT.choices):
        for n in comma_list(teams, TEAM, "--agents"):
            results.append(measure(n, transport, steps, size, repeats, domain_id))
            if not as_json:
                r = results[-1]
                click.echo(f"  {r['agents']:4d} agents, {r['transport']:9s}: {r['steps_per_s']:8.0f} steps/s "
                           f"(world process {r['world_cpu_ms_per_step']:.2f} ms CPU a step, of which the core "
                           f"{r['world_step_ms']:.2f}; missed {r['missed_actions']})")
    if as_json:
        emit_json({"size": size, "steps": steps, "results": results})


def register(cli: click.Group) -> None:
    for command in (run, world, agents, planner, train_ros, robot, robots_sim, timeline_report):
        cli.add_command(command)
    bench = cli.commands.get("bench")
    if isinstance(bench, click.Group):
        bench.add_command(bench_ros)
    scenarios = cli.commands.get("scenarios")
    if isinstance(scenarios, click.Group):
        scenarios.add_command(scenarios_starts)
