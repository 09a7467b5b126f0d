#!/usr/bin/env python3
"""Drive one ForMIC agent from your own ROS 2 node.

This is how a robot's policy node replaces a simulated agent: start the system with that agent
left out (``formic run --external 2``), then run a node named ``agent_2`` in the ``/formic``
namespace that answers every observation on ``/formic/agent_2/observation`` with an action on
``/formic/agent_2/action`` carrying the same step. It first claims its agent on
``/formic/claims`` (latched); the world takes actions for an agent only from its owner and says
who owns what on ``/formic/owners`` (a second node claiming agent 2 is refused and idles). The
world waits for it like for any other agent (and gives it NO_ACTION for a step it misses).

    python examples/external_agent.py --agent 2

Needs only rclpy and formic_interfaces. The decision rule here is deliberately simple: join a
queue when that is possible, otherwise take a random valid move.
"""

from __future__ import annotations

import argparse
import json
import os
import random

JOIN = 4  # actions: 0 north, 1 east, 2 south, 3 west, 4 join


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--agent", type=int, required=True, help="agent id to drive")
    parser.add_argument("--namespace", default="/formic")
    parser.add_argument("--domain-id", type=int, help="ROS_DOMAIN_ID of the run (as `formic run --domain-id`)")
    parser.add_argument("--seed", type=int, default=0, help="seed of the random moves")
    args = parser.parse_args()
    # Discover only on this machine, like the rest of the system (unset to reach other hosts).
    os.environ.setdefault("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")

    import rclpy
    from formic_interfaces.msg import AgentAction, AgentObservation
    from rclpy.duration import Duration
    from rclpy.node import Node
    from rclpy.qos import DurabilityPolicy, QoSProfile
    from std_msgs.msg import String

    class ExternalAgent(Node):
        def __init__(self) -> None:
            super().__init__(f"agent_{args.agent}", namespace=args.namespace)
            self.rng = random.Random(args.seed)
            self.done = False
            self.last: AgentAction | None = None
            # Reliable: the QoS of the world's per-agent topics. Actions keep 100 (formic_ros.qos.STREAM_WRITER), so
            # a recorder that falls behind still gets them all; observations depth 1 (formic_ros.qos.LATEST): a node
            # slower than the world answers the newest step, never a backlog.
            # The names are formic_topics.AGENT_ACTION and AGENT_OBSERVATION (literal: this example stands alone).
            self.publisher = self.create_publisher(AgentAction, "~/action", 100)
            self.create_subscription(AgentObservation, "~/observation", self.on_observation, 1)
            # Claim the agent (latched: formic_ros.qos.LATCHED), then follow the world's verdict.
            latched = QoSProfile(depth=1, durability=DurabilityPolicy.TRANSIENT_LOCAL)
            self.token = f"{self.get_fully_qualified_name()}#{os.getpid()}-{random.getrandbits(32):08x}"
            claim = {"owner": self.get_fully_qualified_name(), "token": self.token, "agents": [args.agent]}
            self.create_publisher(String, f"{args.namespace}/claims", latched).publish(String(data=json.dumps(claim)))
            self.create_subscription(String, f"{args.namespace}/owners", self.on_owners, latched)
            self.owned = False

        def on_owners(self, msg: String) -> None:
            owner = json.loads(msg.data)["owners"].get(str(args.agent))
            refused = owner is not None and owner != self.token
            if refused and (self.owned or not getattr(self, "told", False)):
                self.told = True
                self.get_logger().error(f"agent {args.agent} is driven by another node ({owner}); not driving it")
            self.owned = owner == self.token

        def on_observation(self, obs: AgentObservation) -> None:
            if not self.owned and not obs.done:
                return
            if obs.done:
                self.get_logger().info(f"episode over at step {obs.step}")
                self.done = True
                return
            if self.last is not None and self.last.step == obs.step:
                self.publisher.publish(self.last)  # the world re-sent this step: same answer
                return
            valid = [a for a in range(5) if obs.action_mask[a]]
            action = JOIN if JOIN in valid else self.rng.choice(valid or [0])
            self.last = AgentAction(step=obs.step, agent_id=args.agent, action=action)
            self.publisher.publish(self.last)

    if args.domain_id is not None:
        os.environ["ROS_DOMAIN_ID"] = str(args.domain_id)
    try:  # ForMIC's DDS settings (loopback-only transports, fast repair) when it is installed
        from formic_ros.env import configure_this_process

        configure_this_process(args.domain_id)
    except ImportError:
        pass
    rclpy.init()
    node = ExternalAgent()
    node.get_logger().info(f"driving agent {args.agent}")
    try:
        while rclpy.ok() and not node.done:
            rclpy.spin_once(node, timeout_sec=0.2)
        node.publisher.wait_for_all_acked(Duration(seconds=5))  # a recorder that lags still gets the last actions
    except KeyboardInterrupt:
        pass
    finally:
        node.destroy_node()
        rclpy.try_shutdown()


if __name__ == "__main__":
    main()
