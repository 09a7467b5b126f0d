"""ROS commands: ``formic run`` (the whole system), ``formic world | agents | planner`` (one node
each, for running nodes on several machines) and ``formic bench ros``. Registered by
``formic_cli.main`` when this module imports (it needs rclpy and formic_interfaces only
inside the commands)."""

from __future__ import annotations

import signal
import sys

import click

from .options import hosts_network_option, option_group, scenario_from, team_options, view_options, world_options
from .summary import emit_json, print_episode_summary

NAMESPACE_HELP = "ROS namespace of the ForMIC topics and nodes."
DOMAIN_HELP = "ROS_DOMAIN_ID for this run (default: the environment's, else 0)."
DEADLINE_HELP = "Lockstep: how long a step waits for the last action."
# the world's: --namespace --domain-id --deadline-ms --startup-timeout --rate --viewer-every
lockstep_options = option_group(
    click.option("--namespace", default="/formic", show_default=True, help=NAMESPACE_HELP),
    click.option("--domain-id", type=int, help=DOMAIN_HELP),
    click.option("--deadline-ms", default=1000.0, show_default=True, help=DEADLINE_HELP),
    click.option("--startup-timeout", default=60.0, show_default=True, help="Seconds step 0 waits for every agent."),
    click.option("--rate", type=float, help="Free-running: steps per second, not waiting for agents."),
    click.option("--viewer-every", default=10, show_default=True, help="Publish map and markers every k steps (0: never)."),
)


def _print_ros_summary(summary: dict) -> None:
    print_episode_summary(summary)
    rejected = summary.get("rejected_actions", {})
    click.echo(
        f"ROS: {summary['mode']}, {summary['steps_per_s']:.0f} steps/s after a {summary['startup_s']:.1f} s start; "
        f"missed actions {summary['missed_actions']}; rejected actions "
        + (", ".join(f"{k} {v}" for k, v in rejected.items()) if rejected else "0")
    )
    click.echo(f"state digest {summary['state_digest']}")


def _parse_external(text: str | None) -> tuple[int, ...]:
    from formic_runtime.team import parse_ids

    if not text:
        return ()
    try:
        return tuple(parse_ids(text))
    except ValueError as exc:
        raise click.BadParameter(str(exc), param_hint="--external") from exc


def _sigterm_as_interrupt() -> None:
    def handler(signum, frame):
        raise KeyboardInterrupt

    signal.signal(signal.SIGTERM, handler)


# ----------------------------------------------------------------------------------- run
@click.command()
@hosts_network_option
@world_options
@team_options
@click.option("--hosts", default=1, show_default=True, help="Agent host processes to split the team over.")
@click.option("--transport", type=click.Choice(["per-agent", "batched"]), default="per-agent", show_default=True,
              help="One node and topic pair per agent, or one batched topic pair per host.")
@click.option("--external", help="Agents driven by your own node on their per-agent topics, e.g. 5 or 0-3.")
@click.option("--record", type=click.Path(file_okay=False), help="Record every topic to this rosbag2 (MCAP) directory.")
@lockstep_options
@click.option("--log-dir", type=click.Path(file_okay=False), help="Write each process's log here instead of stderr.")
@click.option("--timeout", type=float, help="Give up after this many seconds.")
@view_options(wait=False)
@click.option("--json", "as_json", is_flag=True, help="Print one JSON object.")
def run(policy, model, greedy, scenario_file, hosts, transport, external, record, namespace, domain_id,
        deadline_ms, startup_timeout, rate, viewer_every, log_dir, timeout, live_view, view_port, as_json,
        **world_kw) -> None:
    """The main job: world, agent hosts (or the planner) and recorder as separate ROS processes."""
    from formic_ros.launcher import RunOptions, launch

    _sigterm_as_interrupt()
    scenario = scenario_from(scenario_file, world_kw)
    options = RunOptions(
        scenario=scenario, policy=policy, model=model, greedy=greedy, hosts=hosts, transport=transport,
        external=_parse_external(external), record=record, namespace=namespace, domain_id=domain_id,
        deadline_ms=deadline_ms, startup_timeout_s=startup_timeout, rate_hz=rate, viewer_every=viewer_every,
        progress=not as_json and sys.stderr.isatty(), log_dir=log_dir, timeout_s=timeout,
        view_port=view_port if live_view else None,
    )
    if live_view:  # served by the world process (formic_view), announced here where the user looks
        from formic_view import DEFAULT_HOST, address, announcement

        click.echo(announcement(address(DEFAULT_HOST, view_port)), err=True)
    try:
        summary = launch(options)
    except KeyboardInterrupt:
        click.echo("interrupted: every process stopped", err=True)
        sys.exit(130)
    except (RuntimeError, ValueError, FileNotFoundError) as exc:
        raise click.ClickException(str(exc)) from exc
    if as_json:
        emit_json(summary)
    else:
        _print_ros_summary(summary)
        click.echo(f"{summary['hosts']} host process(es), {summary['transport']} transport"
                   + (f"; recording in {summary['recording']}" if "recording" in summary else ""))


# --------------------------------------------------------------------------------- world
@click.command()
@hosts_network_option
@world_options
@click.option("--scenario", "scenario_file", type=click.Path(exists=True, dir_okay=False),
              help="Serve a stored scenario (its configuration wins over world options).")
@click.option("--policy-label", default="", help="Which policies drive the team (recorded in the scenario message).")
@lockstep_options
@click.option("--dt", default=0.1, show_default=True, help="Simulated seconds per step (/clock).")
@click.option("--training-masks", is_flag=True, help="Fill the training-filter masks of ObservationBatch.")
@click.option("--observation-encoding", type=click.Choice(["compact", "float32"]), default="compact", show_default=True,
              help="How ObservationBatch carries observations: compact (lossless, ~10x smaller) or plain float32.")
@click.option("--require-subscriber", "require", multiple=True,
              type=click.Choice(["state", "applied_actions", "observations", "summary", "scenario", "score"]),
              help="Do not start before this topic has a subscriber (e.g. a recorder); repeatable.")
@click.option("--recorders", default=0, show_default=True,
              help="Do not step before this many recorders (`formic record`) have matched every topic; "
                   "recorders already running when the world starts are waited for anyway.")
@click.option("--stay", is_flag=True, help="Keep serving the latched scenario and summary after the episode.")
@click.option("--allow-empty", is_flag=True,
              help="Step through the episode even when no agent answers step 0 (default: exit with an error).")
@click.option("--train-config", type=click.Path(exists=True, dir_okay=False),
              help="Training mode: play --episodes episodes on scenarios drawn as `formic train` draws them "
                   "for this training configuration (a run directory's config.json); world options are ignored.")
@click.option("--episodes", default=1, show_default=True, help="Training mode: episodes to play.")
@click.option("--first-episode", default=0, show_default=True,
              help="Training mode: global episode to start from (a resumed run's).")
@click.option("--progress", is_flag=True, help="Show a progress bar on stderr.")
@view_options(wait=False)
@click.option("--json", "as_json", is_flag=True, help="Print the summary as one JSON line.")
def world(scenario_file, policy_label, namespace, domain_id, deadline_ms, startup_timeout, rate, viewer_every,
          dt, training_masks, observation_encoding, require, recorders, stay, allow_empty, train_config, episodes,
          first_episode, progress, live_view, view_port, as_json, **world_kw) -> None:
    """The world node: owns the simulation and steps it with the agents over ROS."""
    from formic_ros.lockstep import RunError
    from formic_ros.training_world import require_one_world, serve_training_world
    from formic_ros.world_node import WorldNodeOptions, serve_world

    options = WorldNodeOptions(
        namespace=namespace, deadline_s=deadline_ms / 1e3, startup_timeout_s=startup_timeout, rate_hz=rate,
        viewer_every=viewer_every, dt=dt, policy_label=policy_label, training_masks=training_masks,
        observation_encoding=observation_encoding,
        require_subscribers=tuple(require), recorders=recorders, progress=progress, allow_empty=allow_empty,
        view_port=view_port if live_view else None,
    )
    if train_config:
        from formic_trainer.config import load_train_config

        try:
            cfg = load_train_config(train_config)
            require_one_world(cfg)
        except (TypeError, ValueError) as exc:
            raise click.ClickException(f"{train_config}: {exc}") from exc
    try:
        if train_config:
            serve_training_world(cfg, episodes, options, first_episode=first_episode, domain_id=domain_id,
                                 on_episode=emit_json if as_json else _print_training_episode)
        else:
            serve_world(scenario_from(scenario_file, world_kw), options, domain_id=domain_id,
                        on_summary=emit_json if as_json else _print_ros_summary, stay=stay)
    except KeyboardInterrupt:
        sys.exit(130)
    except RunError as exc:
        raise click.ClickException(str(exc)) from exc


def _print_training_episode(summary: dict) -> None:
    h, w = summary["size"]
    click.echo(f"ep {summary['episode']:6d} | food {summary['food']:6.1f} | {h}x{w}, seed {summary['seed']} | "
               f"I_h {summary['highway_intensity']:.2f} | missed actions {summary['missed_actions']}")


# -------------------------------------------------------------------------------- agents
@click.command()
@hosts_network_option
@click.option("--ids", required=True, help="Agents this host drives, e.g. 0-31 or 0-3,8-11.")
@click.option("--policy", default="formic", show_default=True,
              help="Policy, or a team spec with global ids such as formic:0-15,csaf11:16-31.")
@click.option("--model", type=click.Path(dir_okay=False), help="Checkpoint for the formic policy.")
@click.option("--greedy", is_flag=True, help="Learned agents take the most likely action.")
@click.option("--transport", type=click.Choice(["per-agent", "batched"]), default="per-agent", show_default=True)
@click.option("--namespace", default="/formic", show_default=True, help=NAMESPACE_HELP)
@click.option("--domain-id", type=int, help=DOMAIN_HELP)
@click.option("--name", help="Node name of the host (default agent_host_<pid>).")
@click.option("--threads", default=1, show_default=True, help="Torch threads for learned agents.")
@click.option("--once", is_flag=True, help="Exit when the episode ends (default: serve episode after episode).")
@click.option("--train-config", type=click.Path(exists=True, dir_okay=False),
              help="Learning mode (batched transport): the agents act and send rollouts for the trainer node "
                   "under this training configuration (a run directory's config.json); --policy is ignored.")
@click.option("--switch-weights", type=click.Choice(["chunk", "episode"]), default="chunk", show_default=True,
              help="Learning mode: wait for each rollout's update and act on with it (as `formic train`), "
                   "or never wait and take the newest weights at each episode start.")
@click.option("--episodes", type=int, help="Learning mode: exit after this many episodes.")
@click.option("--first-episode", default=0, show_default=True,
              help="Learning mode: global episode number of the first episode (a resumed run's).")
def agents(ids, policy, model, greedy, transport, namespace, domain_id, name, threads, once, train_config,
           switch_weights, episodes, first_episode) -> None:
    """An agent host: many agents (each its own node by default) in one process."""
    from formic_ros.agent_host import serve_agents
    from formic_ros.lockstep import WorldLost
    from formic_runtime.team import parse_ids

    try:
        agent_ids = parse_ids(ids)
        if train_config:
            from formic_ros.learning_host import serve_learning_agents
            from formic_trainer.config import load_train_config

            if transport != "batched":
                raise click.UsageError("learning mode (--train-config) needs --transport batched")
            serve_learning_agents(agent_ids, load_train_config(train_config), switch=switch_weights,
                                  first_episode=first_episode, namespace=namespace, name=name,
                                  episodes=1 if once else episodes, domain_id=domain_id, torch_threads=threads)
            return
        serve_agents(agent_ids, policy, model=model, greedy=greedy, transport=transport, namespace=namespace,
                     name=name, once=once, domain_id=domain_id, torch_threads=threads)
    except (ValueError, FileNotFoundError, WorldLost) as exc:
        raise click.ClickException(str(exc)) from exc
    except KeyboardInterrupt:
        sys.exit(130)


# ------------------------------------------------------------------------------ training
@click.command("train-ros")
@hosts_network_option
@click.option("--preset", default="cpu", show_default=True, type=click.Choice(["cpu", "paper"]))
@click.option("--train-config", type=click.Path(exists=True, dir_okay=False),
              help="Start from this training configuration (a run directory's config.json) instead of --preset.")
@click.option("--set", "overrides", multiple=True, metavar="KEY=VALUE",
              help="Override a training field (one world: --set teams=N).")
@click.option("--run-dir", type=click.Path(file_okay=False), default="runs/formic-ros", show_default=True,
              help="Checkpoints (latest.pt) and TensorBoard logs; resumed unless --fresh.")
@click.option("--episodes", type=int, required=True, help="Environment episodes to add in this call.")
@click.option("--fresh", is_flag=True, help="Ignore an existing checkpoint in --run-dir.")
@click.option("--switch-weights", type=click.Choice(["chunk", "episode"]), default="chunk", show_default=True,
              help="Hosts wait for each rollout's update (as `formic train`), or take new weights per episode.")
@click.option("--namespace", default="/formic", show_default=True, help=NAMESPACE_HELP)
@click.option("--domain-id", type=int, help=DOMAIN_HELP)
@click.option("--deadline-ms", default=120000.0, show_default=True,
              help="Lockstep deadline; a step can wait for an update, so it is long.")
@click.option("--startup-timeout", default=120.0, show_default=True, help="Seconds step 0 waits for every agent.")
@click.option("--viewer-every", default=0, show_default=True, help="Publish map and markers every k steps (0: never).")
@click.option("--log-dir", type=click.Path(file_okay=False), help="Write each process's log here instead of stderr.")
@click.option("--timeout", type=float, help="Give up after this many seconds.")
@click.option("--json", "as_json", is_flag=True, help="Print one JSON object at the end.")
def train_ros(preset, train_config, overrides, run_dir, episodes, fresh, switch_weights, namespace, domain_id,
              deadline_ms, startup_timeout, viewer_every, log_dir, timeout, as_json) -> None:
    """Distributed training: trainer node, world (training scenarios) and a learning host as
    separate ROS processes; same settings and seeds give `formic train`'s learning curve."""
    from formic_ros.launcher import TrainRunOptions, launch_training

    from .ros_record_commands import training_config

    _sigterm_as_interrupt()
    try:
        cfg = training_config(preset, train_config, overrides)
        options = TrainRunOptions(
            config=cfg, run_dir=run_dir, episodes=episodes, fresh=fresh, switch=switch_weights, namespace=namespace,
            domain_id=domain_id, deadline_ms=deadline_ms, startup_timeout_s=startup_timeout,
            viewer_every=viewer_every, log_dir=log_dir, timeout_s=timeout,
            on_episode=None if as_json else _print_training_episode,
        )
        result = launch_training(options)
    except KeyboardInterrupt:
        click.echo("interrupted: every process stopped (the trainer saved its checkpoint)", err=True)
        sys.exit(130)
    except (RuntimeError, ValueError, TypeError, FileNotFoundError) as exc:
        raise click.ClickException(str(exc)) from exc
    if as_json:
        emit_json(result)
        return
    trainer = result["trainer"]
    click.echo(f"trained {len(result['episodes'])} episodes from episode {result['first_episode']}: weights version "
               f"{trainer['version']} ({trainer['dropped']} rollouts dropped); checkpoint in {run_dir}/latest.pt")


# ------------------------------------------------------------------------------- planner
@click.command()
@hosts_network_option
@click.option("--namespace", default="/formic", show_default=True, help=NAMESPACE_HELP)
@click.option("--domain-id", type=int, help=DOMAIN_HELP)
@click.option("--once", is_flag=True, help="Exit when the episode ends.")
def planner(namespace, domain_id, once) -> None:
    """The centralized planner node: reads the full state, commands every agent."""
    from formic_ros.lockstep import WorldLost
    from formic_ros.planner_node import serve_planner

    try:
        mismatches = serve_planner(namespace, once=once, domain_id=domain_id)
    except KeyboardInterrupt:
        sys.exit(130)
    except WorldLost as exc:
        raise click.ClickException(str(exc)) from exc
    if mismatches:
        raise click.ClickException(f"the planner's replica differed from the world {mismatches} time(s)")


# --------------------------------------------------------------------------------- bench
@click.command("ros")
@click.option("--agents", "teams", default="16,64,128", show_default=True, help="Team sizes.")
@click.option("--transports", default="batched,per-agent", show_default=True)
@click.option("--steps", default=300, show_default=True, help="Lockstep steps per measurement.")
@click.option("--size", default=64, show_default=True, help="World side.")
@click.option("--repeats", default=1, show_default=True, help="Launches per setting (the best is kept).")
@click.option("--domain-id", type=int, help=DOMAIN_HELP)
@click.option("--json", "as_json", is_flag=True)
def bench_ros(teams, transports, steps, size, repeats, domain_id, as_json) -> None:
    """Lockstep steps/s of world + one host process over ROS, random policy (messaging cost)."""
    from formic_ros.bench import bench_ros as measure

    results = []
    for transport in transports.split(","):
        for n in teams.split(","):
            results.append(measure(int(n), transport.strip(), steps, size, repeats, domain_id))
            if not as_json:
                r = results[-1]
                click.echo(f"  {r['agents']:4d} agents, {r['transport']:9s}: {r['steps_per_s']:8.0f} steps/s "
                           f"(world process {r['world_cpu_ms_per_step']:.2f} ms CPU a step, of which the core "
                           f"{r['world_step_ms']:.2f}; missed {r['missed_actions']})")
    if as_json:
        emit_json({"size": size, "steps": steps, "results": results})


def register(cli: click.Group) -> None:
    for command in (run, world, agents, planner, train_ros):
        cli.add_command(command)
    bench = cli.commands.get("bench")
    if isinstance(bench, click.Group):
        bench.add_command(bench_ros)
