"""World options shared by every command that builds a world (sim, run, eval, scenarios)."""

from __future__ import annotations

import functools

import click

from formic_view import DEFAULT_HOST, DEFAULT_PORT
from formic_world import WorldConfig


def world_options(func):
    """Add --agents --size --steps --seed --obstacles --resources --wipeouts --variant
    --view-size --no-pheromones --timing."""
    options = [
        click.option("--agents", default=32, show_default=True, help="Team size."),
        click.option("--size", default=128, show_default=True, help="World side (square)."),
        click.option("--steps", default=512, show_default=True, help="Episode length."),
        click.option("--seed", default=0, show_default=True, help="Scenario seed."),
        click.option("--obstacles", default=0.0, show_default=True, help="Obstacle density."),
        click.option("--resources", type=click.Choice(["infinite", "finite"]), default="infinite",
                     show_default=True, help="Resource capacity."),
        click.option("--wipeouts", default=0, show_default=True, help="Pheromone wipeouts of 100 steps."),
        click.option("--variant", type=click.Choice(["standard", "flat", "noisy", "random"]),
                     default="standard", show_default=True, help="Pheromone variant."),
        click.option("--view-size", default=11, show_default=True, help="Observation window (5, 11, 21)."),
        click.option("--no-pheromones", is_flag=True, help="Agents see an empty pheromone channel."),
        click.option("--timing", type=click.Choice(["reference", "nominal"]), default="reference",
                     show_default=True, help="Service timing (SPEC §1): the reference code's (a load "
                     "takes 11 steps; a queue that moves up serves nobody that step) or exactly 1/rate."),
    ]
    for option in reversed(options):
        func = option(func)

    @functools.wraps(func)
    def wrapper(*args, **kwargs):
        return func(*args, **kwargs)

    return wrapper


WORLD_OPTION_NAMES = ("agents", "size", "steps", "seed", "obstacles", "resources", "wipeouts",
                      "variant", "view_size", "no_pheromones", "timing")


def world_config_from(kwargs: dict) -> tuple[WorldConfig, int]:
    """Pop the world options out of a command's kwargs; returns (config, seed)."""
    values = {name: kwargs.pop(name) for name in WORLD_OPTION_NAMES}
    try:
        config = WorldConfig(
            height=values["size"], width=values["size"], n_agents=values["agents"],
            episode_steps=values["steps"], obstacle_density=values["obstacles"],
            capacity=values["resources"], wipeouts=values["wipeouts"],
            pheromone_variant=values["variant"], view_size=values["view_size"],
            pheromones_visible=not values["no_pheromones"], timing=values["timing"],
        )
    except ValueError as exc:
        raise click.BadParameter(str(exc)) from exc
    return config, values["seed"]


def view_options(wait: bool = True):
    """Add --view and --view-port (and --view-wait): the live view (formic_view) of a run."""

    def decorate(func):
        options = [
            click.option("--view", "live_view", is_flag=True,
                         help="Serve a live view of the run while it goes (Foxglove WebSocket; open it in "
                              "Foxglove or Lichtblick)."),
            click.option("--view-port", default=DEFAULT_PORT, show_default=True,
                         help=f"Port of the live view (on {DEFAULT_HOST}; 0: any free port)."),
        ]
        if wait:
            options.append(click.option("--view-wait", is_flag=True,
                                        help="With --view: start stepping once a viewer has subscribed."))
        for option in reversed(options):
            func = option(func)
        return func

    return decorate


def open_live_view(port: int, wait: bool = False):
    """Start the live view and print its address (on stderr: stdout may carry --json);
    with ``wait``, return once a viewer has subscribed."""
    from formic_view import LiveView, announcement

    try:
        view = LiveView(port=port)
    except OSError as exc:
        raise click.ClickException(str(exc)) from exc
    click.echo(announcement(view.url), err=True)
    if wait:
        click.echo("live view: waiting for a viewer to subscribe (Ctrl-C to give up)", err=True)
        while not view.wait_for_viewer(0.2):
            pass
    return view
