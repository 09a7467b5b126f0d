"""What the ROS graph says about the other nodes of a run: which recorders are there and
whether they have matched every topic the world publishes (so a recording holds every message
from step 0 on)."""

from __future__ import annotations

import time

from rclpy.node import Node

RECORDER_NODE = "recorder"  # the node name of ``formic record`` (and the launcher's recorder)


def recorders_present(node: Node) -> int:
    """Recorder nodes in ``node``'s namespace (a world waits for those present at start)."""
    namespace = node.get_namespace()
    return sum(name == RECORDER_NODE and ns == namespace for name, ns in node.get_node_names_and_namespaces())


def recorders_matched(node: Node, publishers, expected: int = 1) -> bool:
    """True when at least ``expected`` recorders subscribe to the topic of every publisher in
    ``publishers`` (rclpy publishers) and every subscription the graph shows there has matched
    the publisher (so nothing published from now on is lost to discovery)."""
    for publisher in publishers:
        infos = node.get_subscriptions_info_by_topic(publisher.topic_name)
        recorders = sum(i.node_name == RECORDER_NODE for i in infos)
        if recorders < expected or publisher.get_subscription_count() < len(infos):
            return False
    return True


def wait_for_recorders(node: Node, executor, publishers, expected: int, timeout_s: float) -> bool:
    """Spin until ``expected`` recorders have matched every publisher (False: timed out)."""
    deadline = time.monotonic() + timeout_s
    while not recorders_matched(node, publishers, expected):
        if time.monotonic() > deadline:
            return False
        executor.spin_once(timeout_sec=0.05)
    return True
