"""Options shared by the commands: the world (sim, run, eval, scenarios) and the team (sim, run)."""

from __future__ import annotations

import click

from formic_view import DEFAULT_HOST, DEFAULT_PORT
from formic_world import WorldConfig


def option_group(*options):
    """A decorator adding these click options (in this order in ``--help``)."""

    def decorate(func):
        for option in reversed(options):
            func = option(func)
        return func

    return decorate


# --agents --size --steps --seed --obstacles --resources --wipeouts --variant --view-size
# --no-pheromones --timing
world_options = option_group(
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
)

team_options = option_group(
    click.option("--policy", default="formic", show_default=True,
                 help="Policy for all agents, or a mix such as formic:0-31,csaf11:32-63."),
    click.option("--model", type=click.Path(dir_okay=False), help="Checkpoint for the formic policy."),
    click.option("--greedy", is_flag=True, help="Learned agents take the most likely action."),
    click.option("--scenario", "scenario_file", type=click.Path(exists=True, dir_okay=False),
                 help="Run a stored scenario (its configuration wins over world options)."),
)


WORLD_OPTION_NAMES = ("agents", "size", "steps", "seed", "obstacles", "resources", "wipeouts",
                      "variant", "view_size", "no_pheromones", "timing")


def scenario_from(scenario_file: str | None, world_kw: dict):
    """The stored scenario, or one generated from the world options."""
    from formic_world import Scenario, generate_scenario

    return Scenario.load(scenario_file) if scenario_file else generate_scenario(*world_config_from(world_kw))


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
    """--view and --view-port (and --view-wait): the live view (formic_view) of a run."""
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
    return option_group(*options)


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


def _hosts_network(ctx, param, value) -> bool:
    if value:
        import os

        os.environ["FORMIC_DDS_NETWORK"] = "hosts"  # read by formic_ros.env in this process and its children
    return value


hosts_network_option = click.option(
    "--hosts-network", is_flag=True, expose_value=False, is_eager=True, callback=_hosts_network,
    help="DDS on every network interface (default: loopback only) for nodes on several machines; this "
         "exposes the domain's UDP ports to anyone on the network, with no DDS security (docs/ros.md).")
