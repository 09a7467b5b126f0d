"""Robot agents in ``formic run --robots IDS [--robots-sim]``: the world's robot settings, one
process of robot bridges (a bridge node per robot and an agent host deciding for them, as
``formic robot``) and, with ``simulate``, ``formic robots-sim`` standing in for the hardware.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

from formic_robots.controller import ControllerSettings
from formic_robots.unicycle import UnicycleLimits
from formic_runtime.registry import policy_class
from formic_runtime.team import Team, format_ids

from ..robots.settings import BridgeSettings, SimSettings
from .node_process import node_spec

BRIDGES = "robot_bridge_host"  # node name of the launched bridges' agent host (a driver of the run)


@dataclass(frozen=True)
class RobotRunOptions:
    agents: tuple[int, ...]
    simulate: bool = False  # start formic robots-sim for them
    cell_size: float = 1.0  # metres a cell (the map frame; origin at 0, 0)
    tolerance: float = 0.1  # metres from a cell's centre that count as in the cell
    cell_s: float = 10.0  # seconds a robot gets per cell before its move counts as failed
    max_speed: float = 0.5  # m/s: the bridges' top speed (and the simulated robots')
    max_turn: float = 2.5  # rad/s
    stall_rate: float = 0.0  # simulated robots: stalls per second of driving (failed moves on purpose)
    seed: int = 0  # simulated robots' noise and stalls

    def world_fields(self) -> dict:
        """The world node's settings for these robots (:class:`WorldNodeOptions` fields)."""
        return {"robots": tuple(self.agents), "cell_size": self.cell_size, "robot_tolerance": self.tolerance,
                "robot_cell_s": self.cell_s}


def check_robots(robots: RobotRunOptions, team: Team) -> None:
    """Robots are decided for one by one: not by the planner, nor by a policy whose memory the
    whole team shares (it lives in one host)."""
    for name, ids in team.groups:
        mine = sorted(set(ids) & set(robots.agents))
        if mine and (name == "planner" or policy_class(name).shares_team_memory):
            raise ValueError(f"robots {format_ids(mine)}: {name} decides for the whole team in one process; "
                             "give the robots a per-agent policy (e.g. formic, csaf11, random)")
    outside = [a for a in robots.agents if a in team.external]
    if outside:
        raise ValueError(f"robots {format_ids(outside)} are --external: run `formic robot --policy none` for them "
                         "by hand, not --robots")


def robot_specs(robots: RobotRunOptions, policy: str, namespace: str, domain_id: int | None,
                model: str | None, greedy: bool) -> dict[str, dict]:
    """The bridges' process (a driver: it claims the robots' agents) and the simulator's."""
    limits = UnicycleLimits(max_linear=robots.max_speed, max_angular=robots.max_turn, linear_accel=2 * robots.max_speed,
                            angular_accel=2 * robots.max_turn, stall_rate=robots.stall_rate)
    # the bridges brake at 3/4 of what the (simulated) robots can, and stop on the spot
    bridge = BridgeSettings(controller=ControllerSettings(
        max_linear=robots.max_speed, max_angular=robots.max_turn, linear_decel=1.5 * robots.max_speed,
        angular_decel=1.5 * robots.max_turn, linear_gain=8.0, angular_gain=8.0, pass_radius=robots.cell_size / 4))
    ids = [int(a) for a in robots.agents]
    specs = {"robots": node_spec("robots", agent_ids=ids, policy=policy, settings=asdict(bridge), namespace=namespace,
                                 name=BRIDGES, model=model, greedy=greedy, once=True, domain_id=domain_id)}
    if robots.simulate:
        sim = SimSettings(cell_size=robots.cell_size, limits=limits, seed=robots.seed)
        specs["robots_sim"] = node_spec("robots_sim", agent_ids=ids, settings=asdict(sim), namespace=namespace,
                                        once=True, domain_id=domain_id)
    return specs
