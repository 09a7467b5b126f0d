"""What every driver process shares about the world it drives: reading the latched scenario,
and noticing that the world has left the graph."""

from __future__ import annotations

import time

from formic_interfaces.msg import ScenarioDescription
from rclpy.node import Node

import formic_topics as topics
from formic_world import Scenario

from .. import convert
from ..errors import WorldLost


def read_scenario(msg: ScenarioDescription, log) -> Scenario | None:
    """The scenario a description carries, or None (logged) when it cannot be read."""
    try:
        return convert.decode_scenario(msg)
    except ValueError as exc:
        log.error(f"ignoring scenario: {exc}")
        return None



class WorldWatch:
    """Notices that the world which published our scenario has left the graph, so a process
    waiting for an episode's end that missed its final message does not wait forever (checked
    every 0.5 s)."""

    PERIOD_S = 0.5

    def __init__(self, node: Node):
        self.node = node
        self.next_check = 0.0

    def ended(self, next_step: int, horizon: int) -> bool:
        """Whether the world has left after its episode ended (only the final message was lost);
        raises :class:`WorldLost` when it left before: ``next_step`` is the first step this
        process has not seen through, of ``horizon`` (-1: no scenario yet, nothing to watch)."""
        now = time.monotonic()
        if horizon < 0 or now < self.next_check:
            return False
        self.next_check = now + self.PERIOD_S
        if self.node.count_publishers(topics.SCENARIO):
            return False
        if next_step < horizon:
            raise WorldLost(f"the world left at step {next_step} of {horizon}, before the episode ended")
        return True
