"""What the world's next reset (or stop) plays: its node's ``seed`` and ``scenario_file``
parameters, built into a scenario exactly as a fresh ``formic world`` would, and refused when
set if they cannot build an episode of this world (:mod:`formic_ros.world.control`)."""

from __future__ import annotations

from rcl_interfaces.msg import SetParametersResult
from rclpy.node import Node
from rclpy.parameter import Parameter

from formic_world import Scenario, WorldConfig, generate_scenario

from ..parameters import declare_settings

RESET_PARAMETERS = {
    "seed": "Seed of the episode the next reset (or stop) generates from the world settings.",
    "scenario_file": "A stored scenario the next reset (or stop) loads instead (same world settings); "
                     "empty: generate from the seed.",
}


class NextEpisode:
    """The reset parameters of one world node (``config``: its world settings, which a reset keeps)."""

    def __init__(self, node: Node, config: WorldConfig, seed: int, scenario_file: str = ""):
        self.node, self.config = node, config
        declare_settings(node, {"seed": seed, "scenario_file": scenario_file},
                         writable=RESET_PARAMETERS, descriptions=RESET_PARAMETERS)
        node.add_on_set_parameters_callback(self._check)

    def scenario(self) -> Scenario:
        """What a fresh ``formic world`` would play with the reset parameters."""
        scenario_file = self.node.get_parameter("scenario_file").value
        if scenario_file:
            return Scenario.load(scenario_file)
        return generate_scenario(self.config, self.node.get_parameter("seed").value)

    def _check(self, parameters: list[Parameter]) -> SetParametersResult:
        """A seed or scenario file that cannot build an episode of this world is refused when set."""
        for parameter in parameters:
            if parameter.name == "seed" and parameter.value < 0:
                return SetParametersResult(successful=False, reason="seed must be >= 0")
            if parameter.name == "scenario_file" and parameter.value:
                try:
                    config = Scenario.load(parameter.value).config
                except (OSError, ValueError) as exc:
                    return SetParametersResult(successful=False, reason=f"{parameter.value}: {exc}")
                if config != self.config:
                    return SetParametersResult(successful=False, reason=(
                        f"{parameter.value} has other world settings than this world's: a reset changes the "
                        "seed or the layout, not the settings"))
        return SetParametersResult(successful=True)
