"""What the ROS graph says about the other nodes of a run: which recorders are there and
whether they have matched every topic the world publishes (so a recording holds every message
from step 0 on).

DDS matches the two ends of a topic separately: a writer can count a recorder's reader as
matched while that reader has not matched the writer yet, and whatever is published in between
never reaches the recording (measured on a loaded machine: 1 run in 6 lost steps 0-1 of a few
per-agent topics). So a recorder also reports, on ``recorder_matches``, how many publishers each
of its readers has matched (:class:`RecorderReports`), and a topic counts as recorded only when
both ends say so."""

from __future__ import annotations

import json
import time

from rclpy.node import Node
from std_msgs.msg import String

from . import qos

RECORDER_NODE = "recorder"  # the node name of ``formic record`` (and the launcher's recorder)


def recorders_present(node: Node) -> int:
    """Recorder nodes in ``node``'s namespace (a world waits for those present at start)."""
    namespace = node.get_namespace()
    return sum(name == RECORDER_NODE and ns == namespace for name, ns in node.get_node_names_and_namespaces())


def recorder_report(recorder: str, subscriptions) -> String:
    """A recorder's report: ``{"recorder": its id, "publishers": {topic: publishers its reader
    has matched}}`` over its rclpy ``subscriptions``."""
    return String(data=json.dumps({"recorder": recorder,
                                   "publishers": {s.topic_name: s.get_publisher_count() for s in subscriptions}}))


class RecorderReports:
    """The recorders' reports as ``node`` hears them: the latest per recorder."""

    def __init__(self, node: Node):
        self.node = node
        self.publishers: dict[str, dict[str, int]] = {}  # recorder id -> topic -> publishers matched
        node.create_subscription(String, qos.RECORDER_MATCHES, self._on_report, qos.reliable(100, latched=True))

    def _on_report(self, msg: String) -> None:
        try:
            report = json.loads(msg.data)
            self.publishers[str(report["recorder"])] = {str(t): int(n) for t, n in report["publishers"].items()}
        except (ValueError, KeyError, TypeError, AttributeError):
            self.node.get_logger().warning(f"malformed report on {qos.RECORDER_MATCHES}: {msg.data[:80]!r}",
                                           throttle_duration_sec=10.0)

    def confirming(self, topic: str) -> int:
        """How many recorders report a reader on ``topic`` that has matched every publisher
        this node's graph shows there (at least one)."""
        needed = max(1, self.node.count_publishers(topic))
        return sum(matched.get(topic, 0) >= needed for matched in self.publishers.values())


def recorders_matched(node: Node, publishers, expected: int, reports: RecorderReports) -> bool:
    """True when at least ``expected`` recorders record the topic of every publisher in
    ``publishers`` (rclpy publishers): the publisher has matched every subscription the graph
    shows there, and as many recorders report that their reader has matched it (so nothing
    published from now on is lost to discovery)."""
    for publisher in publishers:
        infos = node.get_subscriptions_info_by_topic(publisher.topic_name)
        recorders = sum(i.node_name == RECORDER_NODE for i in infos)
        if recorders < expected or publisher.get_subscription_count() < len(infos):
            return False
        if expected and reports.confirming(publisher.topic_name) < expected:
            return False
    return True


def wait_for_recorders(node: Node, executor, publishers, expected: int, reports: RecorderReports,
                       timeout_s: float) -> bool:
    """Spin until ``expected`` recorders have matched every publisher (False: timed out)."""
    deadline = time.monotonic() + timeout_s
    while not recorders_matched(node, publishers, expected, reports):
        if time.monotonic() > deadline:
            return False
        executor.spin_once(timeout_sec=0.05)
    return True
