"""``formic actor``: one actor (a world of the training config and the learning host acting in
it) for a trainer elsewhere (``formic trainer --actors K``); docs/ros.md, "Actors"."""

from __future__ import annotations

import click

from .options import (POSITIVE, OutputFolder, hosts_network_option, json_option, preset_option, ros_options,
                      train_config_option, training_config)
from .summary import click_errors, emit


def _print_episode(summary: dict) -> None:
    click.echo(f"episode {summary['episode']}: food {summary['food']:.0f}", err=True)


@click.command("actor")
@hosts_network_option
@preset_option
@train_config_option
@click.option("--set", "overrides", multiple=True, metavar="KEY=VALUE", help="Override a training field.")
@click.option("--actor", "actor", type=click.IntRange(min=0), required=True,
              help="Which world of the config this actor plays (0 to worlds-1), unique among the trainer's actors.")
@click.option("--episodes", type=click.IntRange(min=1), required=True, help="Episodes of this actor's world.")
@click.option("--first-episode", type=click.IntRange(min=0), default=0, show_default=True,
              help="Global episode to start at (a resumed trainer's checkpoint episode count).")
@click.option("--deadline-ms", type=POSITIVE, default=120000.0, show_default=True,
              help="Lockstep deadline; a step can wait for an update, so it is long.")
@click.option("--startup-timeout", "startup_timeout_s", type=POSITIVE, default=120.0, show_default=True,
              help="Seconds step 0 waits for the learning host.")
@click.option("--switch-weights", "switch", type=click.Choice(["chunk", "newest"]), default="chunk", show_default=True,
              help="Wait for each update (a synchronous trainer), or act on with the newest weights "
                   "(`formic trainer --actors K --asynchronous`).")
@click.option("--log-dir", type=OutputFolder(), help="Write each process's log here.")
@click.option("--timeout", "timeout_s", type=POSITIVE, help="Give up after this many seconds.")
@ros_options()
@json_option(help="Print one JSON object at the end.")
def actor_command(preset, train_config, overrides, actor, first_episode, as_json, **options) -> None:
    """One actor of distributed training: world ACTOR of the config and its learning host,
    sending rollouts to and taking weights from `formic trainer --actors K` in --namespace."""
    from formic_ros.launch.actors import launch_actor
    from formic_ros.launch.launcher import TrainRunOptions

    with click_errors(RuntimeError, ValueError, TypeError, FileNotFoundError, interrupted="interrupted"):
        cfg = training_config(preset, train_config, overrides)
        result = launch_actor(TrainRunOptions(config=cfg, run_dir="", **options,
                                              on_episode=None if as_json else _print_episode), actor, first_episode)
    emit(as_json, result, f"actor {actor}: {len(result['episodes'])} episodes from episode {first_episode}")


def register(cli: click.Group) -> None:
    cli.add_command(actor_command)
