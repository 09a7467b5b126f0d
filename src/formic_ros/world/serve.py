"""The world process's composition root: the world node, its simulation_interfaces control
and the world lock, in one ROS session (``formic world``; ``formic run`` starts it as a child)."""

from __future__ import annotations

from typing import Callable

from formic_world import Scenario

from ..env import ros_session
from .control import SimulationControl
from .lock import world_lock
from .node import WorldNode
from .options import WorldNodeOptions


def serve_world(scenario: Scenario, options: WorldNodeOptions, domain_id: int | None = None,
                on_summary: Callable[[dict], None] | None = None, stay: bool = False,
                scenario_file: str = "") -> dict | None:
    """Run the world node in this process, controllable through simulation_interfaces
    (:mod:`formic_ros.world.control`): it plays one episode and returns its summary, or, with
    ``options.paused``, waits for a client and serves episode after episode until told to quit
    (then the last summary, None if no episode ended). ``on_summary`` gets each summary as soon
    as its episode ends; with ``stay`` the node then keeps serving the latched scenario and
    summary until interrupted. ``scenario_file``: where ``scenario`` came from, if from a file
    (a reset loads it again)."""
    with world_lock(options.namespace, domain_id), ros_session(domain_id) as executor:
        node = WorldNode(scenario, options)
        executor.add_node(node)
        control = SimulationControl(node, executor, scenario_file, stays=options.paused or stay)
        try:
            return control.serve(on_summary)
        except KeyboardInterrupt:
            if stay and control.summary is not None:  # interrupting --stay after the episode is its normal end
                return control.summary
            raise
        finally:
            control.close()
            if node.view is not None:
                node.view.close()
