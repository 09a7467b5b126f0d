"""Robot agents in ``formic run --robots IDS [--robots-sim]``: the world's robot settings, one
process of robot bridges (a bridge node per robot, and an agent host deciding for the robots that
are not ``--external``, as ``formic robot``) and, with ``simulate``, ``formic robots-sim`` standing
in for the hardware. An ``--external`` robot's bridge only drives: the user's node ``agent_K``
decides for it, as for a simulated external agent.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

from formic_robots.unicycle import UnicycleLimits
from formic_runtime.registry import policy_class
from formic_runtime.team import Team, format_ids

from ..robots import settings as defaults
from ..robots.settings import BridgeSettings, SimSettings, controller_settings
from .node_process import node_spec

BRIDGES = "robot_bridge_host"  # node name of the launched bridges' agent host (a driver of the run)


@dataclass(frozen=True)
class RobotRunOptions:
    agents: tuple[int, ...]
    simulate: bool = False  # start formic robots-sim for them
    cell_size: float = 1.0  # metres a cell (the map frame; origin at 0, 0)
    tolerance: float = defaults.ROBOT_TOLERANCE
    cell_s: float = defaults.ROBOT_CELL_S
    max_speed: float = defaults.MAX_SPEED
    max_turn: float = defaults.MAX_TURN
    stall_s: float = defaults.STALL_S  # the bridges' "blocked" time
    cmd_vel: str = defaults.CMD_VEL  # the robots' topics ({id} or {agent}: the agent id)
    odom: str = defaults.ODOM
    odom_origin: str = defaults.ODOM_ORIGIN
    stall_rate: float = 0.0  # simulated robots: stalls per second of driving (failed moves on purpose)
    seed: int = 0  # simulated robots' noise and stalls

    def world_fields(self) -> dict:
        """The world node's settings for these robots (:class:`WorldNodeOptions` fields)."""
        return {"robots": tuple(self.agents), "cell_size": self.cell_size, "robot_tolerance": self.tolerance,
                "robot_cell_s": self.cell_s}


def topic_template(text: str) -> str:
    """A robot topic template with ``{id}`` (as ``formic run`` writes it) in ``formic robot``'s
    ``{agent}``; refuses any other field."""
    template = text.replace("{id}", "{agent}")
    try:
        template.format(agent=0)
    except (KeyError, IndexError, ValueError):
        raise ValueError(f"robot topic {text!r}: the only field is {{id}} (the agent id)") from None
    return template


def check_robots(robots: RobotRunOptions, team: Team, n_agents: int) -> None:
    """Robots are agents of the team, decided for one by one: by their own node (``--external``)
    or a per-agent policy, not by the planner, nor by a policy whose memory the whole team shares
    (it lives in one host). Simulated robots publish map-frame odometry on the default topics."""
    outside = [a for a in robots.agents if not 0 <= a < n_agents]
    if outside:
        raise ValueError(f"--robots {format_ids(outside)}: not agents of this team of {n_agents} (0-{n_agents - 1})")
    for name, ids in team.groups:
        mine = sorted(set(ids) & set(robots.agents))
        if mine and (name == "planner" or policy_class(name).shares_team_memory):
            raise ValueError(f"robots {format_ids(mine)}: {name} decides for the whole team in one process; "
                             "give the robots a per-agent policy (e.g. formic, csaf11, random) or leave them "
                             "--external")
    if robots.simulate and robots.odom_origin != defaults.ODOM_ORIGIN:
        raise ValueError("--robot-odom-origin is for real robots: the simulated robots' odometry is in the map frame")
    for template in (robots.cmd_vel, robots.odom):
        topic_template(template)


def robot_specs(robots: RobotRunOptions, team: Team, policy: str, namespace: str, domain_id: int | None,
                model: str | None, greedy: bool) -> dict[str, dict]:
    """The bridges' process (a driver: it claims the robots it decides for) and the simulator's."""
    ids = [int(a) for a in robots.agents]
    bridge = BridgeSettings(cmd_vel=topic_template(robots.cmd_vel), odom=topic_template(robots.odom),
                            odom_origin=robots.odom_origin, stall_s=robots.stall_s,
                            controller=controller_settings(robots.max_speed, robots.max_turn, robots.cell_size))
    external = [a for a in ids if a in team.external]
    specs = {"robots": node_spec("robots", agent_ids=ids, policy=policy, settings=asdict(bridge), namespace=namespace,
                                 name=BRIDGES, model=model, greedy=greedy, once=True, domain_id=domain_id,
                                 external=external)}
    if robots.simulate:  # the simulated robots can do what the bridges command, accelerating at twice the top speed
        limits = UnicycleLimits(max_linear=robots.max_speed, max_angular=robots.max_turn,
                                linear_accel=2 * robots.max_speed, angular_accel=2 * robots.max_turn,
                                stall_rate=robots.stall_rate)
        sim = SimSettings(cmd_vel=bridge.cmd_vel, odom=bridge.odom, cell_size=robots.cell_size, limits=limits,
                          seed=robots.seed)
        specs["robots_sim"] = node_spec("robots_sim", agent_ids=ids, settings=asdict(sim), namespace=namespace,
                                        once=True, domain_id=domain_id)
    return specs
