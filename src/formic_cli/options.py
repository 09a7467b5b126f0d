"""Options shared by the commands: the world and the team (sim, run, world, scenarios), the live
view, ROS (namespace, domain, network) and ``--json``."""

from __future__ import annotations

import math

import click

from formic_topics import DEFAULT_NAMESPACE
from formic_view import DEFAULT_HOST, DEFAULT_PORT
from formic_world import WorldConfig
from formic_world.config import MIN_SIDE, PHEROMONE_VARIANTS
from formic_world.limits import MAX_AGENTS, MAX_EPISODE_STEPS, MAX_SIDE, MAX_VIEW_SIZE

from .summary import click_errors

NAMESPACE_HELP = "ROS namespace of the ForMIC topics and nodes."
RUN_DOMAIN_HELP = "ROS_DOMAIN_ID for this run (default: the environment's, else 0)."
PROCESS_DOMAIN_HELP = "ROS_DOMAIN_ID for this process (default: the environment's)."


# The world's bounds as click types, so that a value out of them is a usage error naming its option.
SIDE = click.IntRange(MIN_SIDE, MAX_SIDE)
TEAM = click.IntRange(1, MAX_AGENTS)
EPISODE_STEPS = click.IntRange(1, MAX_EPISODE_STEPS)
OBSTACLES = click.FloatRange(0, 0.5, max_open=True)
SEED = click.IntRange(min=0)  # numpy's generators take no negative seed
PORT = click.IntRange(0, 65535)
COUNT = click.IntRange(min=1)
DOMAIN_ID = click.IntRange(0, 232)  # Fast DDS derives its ports from the domain id


class OutputFolder(click.Path):
    """A folder the command creates or writes into, refused at once when it cannot be one (a file
    stands at it or above it), not after the work that fills it."""

    def __init__(self) -> None:
        super().__init__(file_okay=False)

    def convert(self, value, param, ctx):
        from pathlib import Path

        folder = super().convert(value, param, ctx)
        if not str(folder).strip():
            self.fail("an empty name: give a folder", param, ctx)
        above = next((parent for parent in Path(folder).absolute().parents if parent.exists()), None)
        if above is not None and not above.is_dir():
            self.fail(f"{str(folder)!r} cannot be a folder: {above} is a file", param, ctx)
        return folder


class FiniteFloat(click.FloatRange):
    """A float range that also refuses nan and infinities (click's ranges let nan through)."""

    def convert(self, value, param, ctx):
        number = super().convert(value, param, ctx)
        if not math.isfinite(number):
            self.fail(f"{number} is not a finite number", param, ctx)
        return number

    def _describe_range(self) -> str:  # click's, for --help: unbounded, it would read "x<=None"
        return "finite" if self.min is None and self.max is None else super()._describe_range()


POSITIVE = FiniteFloat(min=0, min_open=True)  # seconds, rates, lengths
NON_NEGATIVE = FiniteFloat(min=0)


def comma_list(text: str, kind, option: str, choices=None) -> list:
    """The distinct values of a comma list option, each converted by ``kind`` (a function or a click
    type, such as ``TEAM``) and one of ``choices`` when given."""
    def convert(value: str):
        return kind.convert(value, None, None) if isinstance(kind, click.ParamType) else kind(value)

    hint = f"'{option}'"
    try:
        values = list(dict.fromkeys(convert(v.strip()) for v in text.split(",") if v.strip()))
    except click.BadParameter as exc:  # its message names the value
        raise click.BadParameter(exc.message, param_hint=hint) from exc
    except ValueError as exc:
        raise click.BadParameter(f"{text!r}: {exc}", param_hint=hint) from exc
    if not values:
        raise click.BadParameter("empty list", param_hint=hint)
    unknown = [v for v in values if choices is not None and v not in choices]
    if unknown:
        raise click.BadParameter(f"unknown {', '.join(unknown)}; choose from {', '.join(choices)}",
                                 param_hint=hint)
    return values


def option_group(*options):
    """A decorator adding these click options (in this order in ``--help``)."""

    def decorate(func):
        for option in reversed(options):
            func = option(func)
        return func

    return decorate


# where the grid lies in the map frame (the world's entity poses, the robots' start cells)
map_origin_options = option_group(
    click.option("--origin-x", type=FiniteFloat(), default=0.0, show_default=True,
                 help="Map x of the grid's south-west corner (m)."),
    click.option("--origin-y", type=FiniteFloat(), default=0.0, show_default=True,
                 help="Map y of the grid's south-west corner (m)."),
)


def json_option(help: str | None = "Print one JSON object."):
    return click.option("--json", "as_json", is_flag=True, help=help)


def domain_option(help: str = RUN_DOMAIN_HELP):
    return click.option("--domain-id", type=DOMAIN_ID, help=help)


def rclpy_refusal(exc: Exception) -> str:
    """Why one of rclpy's name validators refused a name: the first line of its exception (the
    lines after it point at the character), without the exception's own prefix."""
    return str(exc).splitlines()[0].split(": ", 1)[-1].rstrip(":")


def ros_namespace(ctx, param, value: str) -> str:
    """A namespace ROS accepts (relative ones are taken from the root, as rclpy does), checked
    here rather than in each node process it is handed to."""
    if value != DEFAULT_NAMESPACE:
        from rclpy.validate_namespace import validate_namespace

        try:
            validate_namespace(value if value.startswith("/") else f"/{value}")
        except Exception as exc:  # rclpy's InvalidNamespaceException
            raise click.BadParameter(rclpy_refusal(exc)) from exc
    return value


def ros_node_name(ctx, param, value: str | None) -> str | None:
    """A node name ROS accepts, checked before any process starts."""
    if value is not None:
        from rclpy.validate_node_name import validate_node_name

        try:
            validate_node_name(value)
        except Exception as exc:  # rclpy's InvalidNodeNameException
            raise click.BadParameter(rclpy_refusal(exc)) from exc
    return value


def ros_options(domain_help: str = RUN_DOMAIN_HELP):
    """--namespace and --domain-id."""
    namespace = click.option("--namespace", default=DEFAULT_NAMESPACE, show_default=True, callback=ros_namespace,
                             help=NAMESPACE_HELP)
    return option_group(namespace, domain_option(domain_help))


def _odd(ctx, param, value: int) -> int:
    if value % 2 == 0:
        raise click.BadParameter(f"{value} is even: the window is centred on its agent (5, 11, 21)")
    return value


def world_option_group(steps: int = 512, steps_help: str = "Episode length."):
    """The world options, with this default episode length. Their parameter names are
    WorldConfig's fields, except --size, --seed and --no-pheromones (see world_config_from)."""
    return option_group(
        click.option("--agents", "n_agents", type=TEAM, default=32, show_default=True, help="Team size."),
        click.option("--size", type=SIDE, default=128, show_default=True, help="World side (square)."),
        click.option("--steps", "episode_steps", type=EPISODE_STEPS, default=steps, show_default=True,
                     help=steps_help),
        click.option("--seed", type=SEED, default=0, show_default=True, help="Scenario seed."),
        click.option("--obstacles", "obstacle_density", type=OBSTACLES, default=0.0,
                     show_default=True, help="Obstacle density."),
        click.option("--resources", "capacity", type=click.Choice(["infinite", "finite"]), default="infinite",
                     show_default=True, help="Resource capacity."),
        click.option("--wipeouts", type=click.IntRange(min=0), default=0, show_default=True,
                     help="Pheromone wipeouts of 100 steps."),
        click.option("--variant", "pheromone_variant", type=click.Choice(PHEROMONE_VARIANTS),
                     default="standard", show_default=True, help="Pheromone variant."),
        click.option("--view-size", type=click.IntRange(3, MAX_VIEW_SIZE), callback=_odd, default=11,
                     show_default=True, help="Observation window, odd (5, 11, 21)."),
        click.option("--no-pheromones", is_flag=True, help="Agents see an empty pheromone channel."),
        click.option("--timing", type=click.Choice(["reference", "nominal"]), default="reference",
                     show_default=True, help="Service timing (SPEC §1): the reference code's (a load "
                     "takes 11 steps; a queue that moves up serves nobody that step) or exactly 1/rate."),
    )


world_options = world_option_group()
WORLD_FIELDS = ("n_agents", "episode_steps", "obstacle_density", "capacity", "wipeouts", "pheromone_variant",
                "view_size", "timing")
WORLD_OPTION_NAMES = (*WORLD_FIELDS, "size", "seed", "no_pheromones")

def _named(ctx, param, value: str | None) -> str | None:
    if value is not None and not value.strip():
        raise click.BadParameter("an empty name: give a file, or leave the option out")
    return value


model_option = click.option("--model", type=click.Path(dir_okay=False), callback=_named,
                            help="Checkpoint for the formic policy.")
greedy_option = click.option("--greedy", is_flag=True, help="Learned agents take the most likely action.")
team_options = option_group(
    click.option("--policy", default="formic", show_default=True,
                 help="Policy for all agents, or a mix such as formic:0-31,csaf11:32-63."),
    model_option,
    greedy_option,
    click.option("--scenario", "scenario_file", type=click.Path(exists=True, dir_okay=False),
                 help="Run a stored scenario (its configuration wins over world options)."),
)

# the training commands' (train, train-ros, trainer)
preset_option = click.option("--preset", default="cpu", show_default=True,
                             type=click.Choice(["cpu", "paper"]))
fresh_option = click.option("--fresh", is_flag=True, help="Ignore an existing checkpoint in --run-dir.")
train_config_option = click.option(
    "--train-config", type=click.Path(exists=True, dir_okay=False),
    help="Start from this training configuration (a run directory's config.json) instead of --preset.")
ros_run_dir_option = click.option(
    "--run-dir", type=OutputFolder(), default="runs/formic-ros", show_default=True,
    help="Checkpoints (latest.pt) and TensorBoard logs; resumed unless --fresh.")


def training_config(preset: str, config_file: str | None, overrides: tuple[str, ...]):
    """``--preset`` (or a stored ``--train-config``) with ``--set`` overrides on top."""
    import dataclasses

    from formic_trainer.config import make_config, parse_overrides

    if config_file:
        return dataclasses.replace(stored_train_config(config_file), **parse_overrides(overrides))
    return make_config(preset, **parse_overrides(overrides))


def stored_train_config(path: str):
    """A run directory's ``config.json``; one that does not read as one is an error naming it."""
    from formic_trainer.config import load_train_config

    with click_errors(OSError, ValueError, TypeError, KeyError, prefix=f"{path}: not a training configuration: "):
        return load_train_config(path)


def scenario_from(scenario_file: str | None, world_kw: dict):
    """The stored scenario, or one generated from the world options (popped from a command's
    kwargs either way)."""
    from formic_world import Scenario, generate_scenario

    world = {name: world_kw.pop(name) for name in WORLD_OPTION_NAMES}
    return Scenario.load(scenario_file) if scenario_file else generate_scenario(*world_config_from(world))


def world_config_from(kwargs: dict) -> tuple[WorldConfig, int]:
    """Pop the world options out of a command's kwargs; returns (config, seed)."""
    fields = {name: kwargs.pop(name) for name in WORLD_FIELDS}
    size, seed = kwargs.pop("size"), kwargs.pop("seed")
    try:
        config = WorldConfig(height=size, width=size, pheromones_visible=not kwargs.pop("no_pheromones"),
                             **fields)
    except ValueError as exc:  # what the option types cannot see: two options together
        hint = "'--wipeouts'" if str(exc).startswith("wipeouts") else None
        raise click.BadParameter(str(exc), param_hint=hint) from exc
    return config, seed


def view_options():
    """--view, --view-port and --view-wait: the live view (formic_view) of a run."""
    return option_group(
        click.option("--view", "live_view", is_flag=True,
                     help="Serve a live view of the run while it goes (Foxglove WebSocket; open it in "
                          "Foxglove or Lichtblick)."),
        click.option("--view-port", type=PORT, default=DEFAULT_PORT, show_default=True,
                     help=f"Port of the live view (on {DEFAULT_HOST}; 0: any free port)."),
        click.option("--view-wait", is_flag=True, help="With --view: start stepping once a viewer has subscribed."),
    )


def live_view_port(live_view: bool, view_port: int, view_wait: bool) -> int | None:
    """The live view's port, or None without --view (--view-wait alone would wait for nothing)."""
    if view_wait and not live_view:
        raise click.UsageError("--view-wait waits for a viewer of the live view: add --view")
    return view_port if live_view else None


def open_live_view(port: int, wait: bool = False):
    """Start the live view and print its address (on stderr: stdout may carry --json);
    with ``wait``, return once a viewer has subscribed."""
    from formic_view import LiveView, announcement

    with click_errors(OSError):
        view = LiveView(port=port)
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


def probe_options(policies: str, teams: str):
    """The options of the measuring scripts (``scripts/nest_crowding.py``,
    ``scripts/trail_following.py``, ``scripts/homing.py``): which policies, the model, the first
    stored scenarios per team size (:func:`stored_teams`) and whether the pheromone channel is empty."""
    return option_group(
        click.option("--policies", default=policies, show_default=True),
        click.option("--model", type=click.Path(exists=True, dir_okay=False), help="Checkpoint of the formic policy."),
        click.option("--scenarios", "scenario_dir", default="eval/readme/scenarios", show_default=True,
                     type=click.Path(exists=True, file_okay=False)),
        click.option("--size", type=SIDE, default=128, show_default=True),
        click.option("--teams", default=teams, show_default=True),
        click.option("--count", default=4, show_default=True, help="Scenarios per team size (the first, by name)."),
        click.option("--channel-empty", is_flag=True,
                     help="Agents read an empty pheromone channel (as formic eval --no-pheromones tests them)."),
    )


def stored_teams(scenario_dir: str, size: int, teams: str, count: int):
    """``(team size, its first count stored scenarios)`` for each of the comma-separated ``teams``;
    a missing or broken scenario set is a clean command-line error."""
    from pathlib import Path

    from formic_world.scenario import ScenarioError
    from formic_world.scenario_sets import first_stored

    for team in comma_list(teams, TEAM, "--teams"):
        try:
            yield team, first_stored(Path(scenario_dir), size, team, count)
        except ScenarioError as exc:
            raise click.ClickException(str(exc)) from exc
