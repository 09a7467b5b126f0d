"""Robot commands (docs/robots.md): ``formic robot`` (bridges between robot agents and robots),
``formic robots-sim`` (simulated robots), ``formic scenarios starts`` (where to put the robots
before a run), and the robot options of ``formic run`` and ``formic world``. Registered by :mod:`formic_cli.ros_commands`."""

from __future__ import annotations

import string

import click

from formic_topics import DEFAULT_NAMESPACE

from .options import (NON_NEGATIVE, POSITIVE, SEED, FiniteFloat, greedy_option, hosts_network_option, json_option,
                      map_origin_options, model_option, option_group, rclpy_refusal, ros_options, scenario_from,
                      world_options)
from .summary import click_errors, emit_json

from formic_ros.robots.settings import (CMD_VEL as DEFAULT_CMD_VEL, MAX_SPEED, MAX_TURN, ODOM as DEFAULT_ODOM,
                                        ROBOT_CELL_S as CELL_S, ROBOT_TOLERANCE as TOLERANCE, STALL_S)


def _ids(ctx, param, text: str | None) -> tuple[int, ...]:
    from formic_runtime.team import parse_ids

    try:
        return () if text is None else tuple(parse_ids(text))
    except ValueError as exc:
        raise click.BadParameter(str(exc), ctx=ctx, param=param) from exc


def _topic(ctx, param, template: str | None) -> str | None:
    """A robot topic template whose only field is the agent id (``{agent}``, or ``{id}`` as
    ``formic run`` writes it, handed on as ``{agent}``: the field the nodes fill) and that makes a
    ROS topic name with known substitutions: checked before any node starts. The field is taken
    bare (no index, attribute, conversion or format) so that every id makes a name when agent 0 does."""
    if template is None or template == param.default:
        return template
    refusal = f"{template!r}: the only field is the agent id, {{agent}} (or {{id}})"
    try:
        fields = [(name, spec, conversion) for _, name, spec, conversion in string.Formatter().parse(template)
                  if name is not None]
    except ValueError:  # a lone brace
        raise click.BadParameter(refusal) from None
    if any(name not in ("agent", "id") or spec or conversion for name, spec, conversion in fields):
        raise click.BadParameter(refusal)
    agent_template = template.replace("{id}", "{agent}")
    from rclpy.expand_topic_name import expand_topic_name
    from rclpy.validate_topic_name import validate_topic_name

    name = agent_template.format(agent=0)
    try:
        validate_topic_name(name)
    except Exception as exc:  # rclpy's InvalidTopicNameException
        raise click.BadParameter(f"{template!r}: {rclpy_refusal(exc)}") from exc
    try:  # what a node does with it: {node}, {ns} and {namespace} are ROS's substitutions, no other
        expand_topic_name(name, "robot_bridge_0", DEFAULT_NAMESPACE)
    except ValueError as exc:  # "...: unknown substitution: {x}, at <rcl's source file>"
        raise click.BadParameter(f"{template!r}: {rclpy_refusal(exc).split(', at ')[0]}") from exc
    return agent_template


def _origin(ctx, param, text: str) -> str:
    """map, start or a finite X,Y,YAW."""
    if text not in ("map", "start"):
        from formic_ros.robots.bridge import parse_origin

        try:
            parse_origin(text)
        except ValueError as exc:
            raise click.BadParameter(str(exc)) from exc
    return text


# the world's (named as WorldNodeOptions' fields)
world_robot_options = option_group(
    click.option("--robots", callback=_ids,
                 help="Robot agents, e.g. 28-31: each step is committed when they have reached their cells."),
    click.option("--robot-tolerance", type=POSITIVE, default=TOLERANCE, show_default=True,
                 help="Metres from a cell's centre that count as a robot being in the cell."),
    click.option("--robot-cell-s", type=POSITIVE, default=CELL_S, show_default=True,
                 help="Seconds a robot gets per cell of a move before the move counts as failed."),
)

# formic run's (popped by robot_run_options)
run_robot_options = option_group(
    world_robot_options,
    click.option("--robots-sim", is_flag=True, help="Simulate the robots (formic robots-sim) instead of real ones."),
    click.option("--cell-size", type=POSITIVE, default=1.0, show_default=True,
                 help="Metres a grid cell (the map frame)."),
    click.option("--robot-max-speed", type=POSITIVE, default=MAX_SPEED, show_default=True,
                 help="Robots' top speed, m/s (formic robot's and robots-sim's --max-speed)."),
    click.option("--robot-max-turn", type=POSITIVE, default=MAX_TURN, show_default=True,
                 help="Robots' top turn rate, rad/s (formic robot's and robots-sim's --max-turn)."),
    click.option("--robot-stall-s", type=POSITIVE, default=STALL_S, show_default=True,
                 help="No progress for this long: the bridge reports the move failed (formic robot's --stall-s)."),
    click.option("--robot-cmd-vel", default="/robot_{id}/cmd_vel", show_default=True, callback=_topic,
                 help="Each robot's geometry_msgs/Twist topic ({id}: the agent id; formic robot's --cmd-vel)."),
    click.option("--robot-odom", default="/robot_{id}/odom", show_default=True, callback=_topic,
                 help="Each robot's nav_msgs/Odometry topic ({id}: the agent id; formic robot's --odom)."),
    click.option("--robot-odom-origin", default="map", show_default=True, callback=_origin,
                 help="Where the odometry frame lies in the map: map, start or X,Y,YAW (formic robot's "
                      "--odom-origin; real robots only)."),
    click.option("--robot-stall-rate", type=NON_NEGATIVE, default=0.0, show_default=True,
                 help="Simulated robots: stalls per second of driving (moves then fail)."),
)


def robot_run_options(fields: dict):
    """Pop ``run_robot_options`` out of a command's kwargs: a RobotRunOptions, or None without --robots."""
    robots, simulate = fields.pop("robots"), fields.pop("robots_sim")
    names = ("tolerance", "cell_s", "max_speed", "max_turn", "stall_s", "cmd_vel", "odom", "odom_origin", "stall_rate")
    settings = {name: fields.pop(f"robot_{name}") for name in names}
    cell_size = fields.pop("cell_size")
    if not robots:
        if simulate:
            raise click.UsageError("--robots-sim needs --robots")
        return None
    from formic_ros.launch.robots import RobotRunOptions

    return RobotRunOptions(agents=robots, simulate=simulate, cell_size=cell_size, seed=fields["seed"], **settings)


@click.command()
@hosts_network_option
@click.option("--agent", "agents", required=True, callback=_ids,
              help="The robot agent(s), e.g. 5 (or 28-31: a bridge node each, one process).")
@click.option("--policy", default="formic", show_default=True,
              help="Who decides for the robot: a policy or team spec as `formic agents --policy`, or none "
                   "(your own node agent_K publishes agent_K/action; leave K --external).")
@model_option
@greedy_option
@click.option("--cmd-vel", default=DEFAULT_CMD_VEL, show_default=True, callback=_topic,
              help="geometry_msgs/Twist topic the robot follows ({agent}: the agent id).")
@click.option("--odom", default=DEFAULT_ODOM, show_default=True, callback=_topic,
              help="nav_msgs/Odometry topic of the robot ({agent}: the agent id).")
@click.option("--pose", callback=_topic,
              help="geometry_msgs/PoseStamped topic in the map frame instead of odometry ({agent}).")
@click.option("--odom-origin", default="map", show_default=True, callback=_origin,
              help="Where the pose's frame lies in the map: map (it is the map frame), start (the robot was switched "
                   "on at its start cell's centre facing east), or X,Y,YAW.")
@click.option("--max-speed", type=POSITIVE, default=MAX_SPEED, show_default=True,
              help="Top speed the bridge commands, m/s.")
@click.option("--max-turn", type=POSITIVE, default=MAX_TURN, show_default=True,
              help="Top turn rate the bridge commands, rad/s.")
@click.option("--stall-s", type=POSITIVE, default=STALL_S, show_default=True,
              help="No progress for this long: the move fails (blocked).")
@ros_options()
@click.option("--once", is_flag=True, help="Exit when the episode ends.")
def robot(agents, policy, model, greedy, cmd_vel, odom, pose, odom_origin, max_speed, max_turn, stall_s, namespace,
          domain_id, once) -> None:
    """Robot bridge: a robot agent's decisions to cmd_vel, the robot's odometry back to its cell."""
    from formic_ros.errors import WorldLost
    from formic_ros.robots.bridge import serve_robots
    from formic_ros.robots.settings import BridgeSettings, controller_settings

    with click_errors(ValueError, FileNotFoundError, WorldLost, interrupted=""):
        controller = controller_settings(max_speed, max_turn)
        settings = BridgeSettings(cmd_vel=cmd_vel, odom=odom, pose=pose, odom_origin=odom_origin, stall_s=stall_s,
                                  controller=controller)
        serve_robots(list(agents), policy, settings, namespace=namespace, model=model, greedy=greedy, once=once,
                     domain_id=domain_id)


@click.command("robots-sim")
@hosts_network_option
@click.option("--robots", "agents", required=True, callback=_ids, help="The robot agents to simulate, e.g. 28-31.")
@click.option("--cell-size", type=POSITIVE, default=1.0, show_default=True,
              help="Metres a cell: the world's --cell-size.")
@click.option("--origin-x", type=FiniteFloat(), default=0.0, show_default=True, help="The world's --origin-x.")
@click.option("--origin-y", type=FiniteFloat(), default=0.0, show_default=True, help="The world's --origin-y.")
@click.option("--max-speed", type=POSITIVE, default=MAX_SPEED, show_default=True, help="m/s")
@click.option("--max-turn", type=POSITIVE, default=MAX_TURN, show_default=True, help="rad/s")
@click.option("--accel", type=POSITIVE, default=1.0, show_default=True, help="m/s^2 (turning: 5x in rad/s^2)")
@click.option("--noise", type=NON_NEGATIVE, default=0.05, show_default=True,
              help="Slip: std. dev. of executed/commanded velocity.")
@click.option("--stall-rate", type=NON_NEGATIVE, default=0.0, show_default=True, help="Stalls per second of driving.")
@click.option("--stall-s", type=POSITIVE, default=3.0, show_default=True, help="Seconds a stall lasts.")
@click.option("--seed", type=SEED, default=0, show_default=True, help="Seed of the noise and the stalls.")
@click.option("--cmd-vel", default=DEFAULT_CMD_VEL, show_default=True, callback=_topic,
              help="Twist topic of each robot ({agent}).")
@click.option("--odom", default=DEFAULT_ODOM, show_default=True, callback=_topic,
              help="Odometry topic of each robot ({agent}).")
@ros_options()
@click.option("--once", is_flag=True, help="Exit when the world leaves.")
def robots_sim(agents, cell_size, origin_x, origin_y, max_speed, max_turn, accel, noise, stall_rate, stall_s, seed,
               cmd_vel, odom, namespace, domain_id, once) -> None:
    """Simulated differential-drive robots: cmd_vel in, odometry and tf out, placed at their agents' start cells."""
    from formic_robots.unicycle import UnicycleLimits
    from formic_ros.robots.settings import SimSettings
    from formic_ros.robots.sim import serve_robots_sim

    with click_errors(ValueError, interrupted=""):
        limits = UnicycleLimits(max_linear=max_speed, max_angular=max_turn, linear_accel=accel,
                                angular_accel=5 * accel, noise=noise, stall_rate=stall_rate, stall_s=stall_s)
        settings = SimSettings(cmd_vel=cmd_vel, odom=odom, cell_size=cell_size, origin=(origin_x, origin_y),
                               limits=limits, seed=seed)
        serve_robots_sim(list(agents), settings, namespace=namespace, once=once, domain_id=domain_id)


@click.command("starts")
@world_options
@click.option("--scenario", "scenario_file", type=click.Path(exists=True, dir_okay=False),
              help="A stored scenario (its configuration wins over world options).")
@click.option("--robots", callback=_ids, help="Only these agents, e.g. 28-31.")
@click.option("--cell-size", type=POSITIVE, default=1.0, show_default=True,
              help="Metres a cell: the run's --cell-size.")
@map_origin_options
@json_option()
def scenarios_starts(scenario_file, robots, cell_size, origin_x, origin_y, as_json, **world_kw) -> None:
    """Each agent's start cell and its centre in the map frame: where to put a robot before a run
    of this scenario (or of these world options: --seed, --size, --agents, ...)."""
    from formic_world.metric_frame import MetricFrame

    scenario = scenario_from(scenario_file, world_kw)
    cfg = scenario.config
    frame = MetricFrame(cfg.height, cfg.width, cell_size, origin_x, origin_y)
    with click_errors(ValueError):
        outside = [a for a in robots if not 0 <= a < cfg.n_agents]
        if outside:
            raise ValueError(f"--robots {outside}: not agents of this team of {cfg.n_agents}")
    rows = []
    for a in robots or range(cfg.n_agents):
        start = scenario.agents[a]
        x, y = frame.cell_centre(start.row, start.col)
        rows.append({"agent": a, "row": int(start.row), "col": int(start.col), "x": x, "y": y})
    if as_json:
        emit_json({"seed": scenario.seed, "size": [cfg.height, cfg.width], "cell_size": cell_size, "starts": rows})
        return
    click.echo(f"seed {scenario.seed}, {cfg.height}x{cfg.width}, {cell_size:g} m cells; x, y: the cell's centre "
               "in the map frame (m), facing east (yaw 0)")
    for row in rows:
        click.echo(f"agent {row['agent']:3d}: cell ({row['row']}, {row['col']}) at x {row['x']:.3f}, y {row['y']:.3f}")
