"""The centralized planner as a node: full state in, every agent's action out.

The planner needs the whole World (queues, reservations, the grid), not an observation, so the
node keeps its own replica: built from the latched scenario and stepped with exactly the
actions the world applied (``applied_actions``). The core is deterministic, so the replica
stays identical to the world's; the node checks this against every ``state`` digest.
After the replica reaches step t it plans and publishes an ActionBatch for all agents.
"""

from __future__ import annotations

import time
from contextlib import suppress

import numpy as np
from formic_interfaces.msg import ActionBatch, ScenarioDescription, WorldState
from rclpy.node import Node

from formic_runtime.registry import make_policy
from formic_runtime.threads import configure_threads
import formic_topics as topics
from formic_world import World

from .. import convert, qos
from ..parameters import declare_settings
from .claim import Claim
from .world_watch import WorldWatch

RESEND_S = 1.0  # re-send the last actions when the world has not moved on for this long


class PlannerNode(Node):
    """Node ``planner``; call :meth:`tick` from the spin loop (it retries unsent actions)."""

    def __init__(self, namespace: str = topics.DEFAULT_NAMESPACE):
        super().__init__("planner", namespace=namespace)
        declare_settings(self, {"policy": "planner", "resend_s": RESEND_S})
        configure_threads()
        self.planner = make_policy("planner")
        self.actions_pub = self.create_publisher(ActionBatch, f"~/{topics.ACTIONS}", qos.STREAM_WRITER)
        self.claim: Claim | None = None  # made when the team size is known
        self.create_subscription(ScenarioDescription, topics.SCENARIO, self._on_scenario, qos.LATCHED)
        self.create_subscription(ActionBatch, topics.APPLIED_ACTIONS, self._on_applied, qos.STREAM)
        self.create_subscription(WorldState, topics.STATE, self._on_state, qos.STREAM)
        self.world: World | None = None
        self.scenario_json = ""
        self.scenario = None
        self.horizon = -1  # its episode's steps (-1: no scenario yet)
        self.pending: ActionBatch | None = None
        self.sent_at = -np.inf
        self.digests: dict[int, str] = {}  # replica digests and world digests not yet compared
        self.world_digests: dict[int, str] = {}
        self.mismatches = 0
        self.finished = False
        self.get_logger().info(f"up: waiting for a world in {namespace}")

    def _on_scenario(self, msg: ScenarioDescription) -> None:
        if msg.scenario_json == self.scenario_json:
            return
        self.scenario_json, self.scenario = msg.scenario_json, convert.decode_scenario(msg)
        self._start()

    def _start(self) -> None:
        """A fresh replica of the scenario at step 0, and the plan for it."""
        scenario = self.scenario
        self.horizon = scenario.config.episode_steps
        self.world = World(scenario)
        self.planner.reset(scenario.config.n_agents, scenario.seed)
        if self.claim is None:  # the planner drives the whole team
            self.claim = Claim(self, range(scenario.config.n_agents), self.actions_pub.topic_name,
                               publishers=[self.actions_pub])
        self.digests, self.world_digests = {0: self.world.state_digest()}, {}
        self.finished = False
        self.get_logger().info(f"scenario seed {scenario.seed}: planning for {scenario.config.n_agents} agents")
        self._plan()

    def _on_applied(self, msg: ActionBatch) -> None:
        world = self.world
        if world is None or world.done or msg.step < world.t:
            return
        if msg.step > world.t:
            self.get_logger().error(
                f"applied actions of step {msg.step} but the replica is at step {world.t} "
                "(the planner joined mid-episode); waiting for the next scenario"
            )
            self.world = None
            return
        world.step(convert.decode_applied(msg, world.config.n_agents))
        self.digests[world.t] = world.state_digest()
        self._compare()
        if world.done:
            self.finished, self.pending = True, None
        else:
            self._plan()

    def _on_state(self, msg: WorldState) -> None:
        if msg.step == 0 and self.scenario is not None and (self.world is None or self.world.t > 0):
            self._start()  # the world started the same scenario again (a simulation_interfaces reset)
        self.world_digests[msg.step] = msg.state_digest
        self._compare()

    def _compare(self) -> None:
        for step in sorted(set(self.digests) & set(self.world_digests)):
            if self.digests.pop(step) != self.world_digests.pop(step):
                self.mismatches += 1
                self.get_logger().error(f"replica differs from the world at step {step}: plans may be wrong")

    def _plan(self) -> None:
        world = self.world
        actions = self.planner.act_world(world)
        self.pending = convert.encode_actions(world.t, np.arange(world.config.n_agents), actions)
        self.sent_at = -np.inf
        self.tick()

    def tick(self) -> None:
        """Publish the pending actions once the world listens; re-send when it stays silent."""
        now = time.monotonic()
        if self.pending is None or now - self.sent_at < RESEND_S or not self.claim.ready():
            return
        self.actions_pub.publish(self.pending)
        self.sent_at = now


def serve_planner(namespace: str = topics.DEFAULT_NAMESPACE, once: bool = False,
                  domain_id: int | None = None) -> int:
    """Plan until interrupted (or, with ``once``, until an episode ends); returns the number
    of replica mismatches seen."""
    from ..env import ros_session

    with ros_session(domain_id) as executor:
        node = PlannerNode(namespace)
        executor.add_node(node)
        watch = WorldWatch(node)
        with suppress(KeyboardInterrupt):
            while not (once and node.finished):
                executor.spin_once(timeout_sec=0.1)
                node.tick()
                next_step = node.world.t + 1 if node.world else 0  # the replica has planned world.t
                if once and not node.finished and watch.ended(next_step, node.horizon):
                    break  # only the final state was lost
        return node.mismatches
