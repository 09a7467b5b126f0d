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
from collections import Counter
from typing import NamedTuple

from rclpy.node import Node
from std_msgs.msg import String

import formic_topics as topics

from . import qos

RECORDER_NODE = "recorder"  # the node name of ``formic record`` (and the launcher's recorder)
REPORT_GRAPH_LAG_S = 2.0  # a report whose sender the graph does not show is dropped only when older than this


def settle_discovery(node: Node, executor, min_s: float = 1.0, quiet_s: float = 0.3, limit_s: float = 2.0) -> None:
    """Spin for at least ``min_s`` and until the graph has shown no new node for ``quiet_s`` (at
    most ``limit_s``): a process that has just started has not discovered the nodes already
    running (on a loaded machine a recorder started before the world was not seen within 0.3 s
    in 1 run of 3, was not waited for, and missed the first steps)."""
    started = changed = time.monotonic()
    seen = set(node.get_node_names_and_namespaces())
    while time.monotonic() - started < limit_s and (
            time.monotonic() - started < min_s or time.monotonic() - changed < quiet_s):
        executor.spin_once(timeout_sec=0.05)
        now = set(node.get_node_names_and_namespaces())
        if now - seen:
            seen, changed = seen | now, time.monotonic()


def recorders_present(node: Node) -> int:
    """Recorder nodes in ``node``'s namespace (a world waits for those present at start)."""
    namespace = node.get_namespace()
    return sum(name == RECORDER_NODE and ns == namespace for name, ns in node.get_node_names_and_namespaces())


def recorder_report(recorder: str, subscriptions) -> String:
    """A recorder's report: ``{"recorder": its id (its node's fully qualified name, ``#`` and a
    token of its own), "publishers": {topic: publishers its reader has matched}}`` over its
    rclpy ``subscriptions``."""
    return String(data=json.dumps({"recorder": recorder,
                                   "publishers": {s.topic_name: s.get_publisher_count() for s in subscriptions}}))


class Report(NamedTuple):
    """One recorder's latest report as a reader holds it."""

    node: str  # the recorder node's fully qualified name
    matched: dict[str, int]  # topic -> publishers its reader has matched
    received: float  # when it came (monotonic s)


class RecorderReports:
    """The recorders' reports as ``node`` hears them: the latest per recorder, counted only while
    its sender publishes reports in the graph. A SIGKILLed recorder says no goodbye, and its
    latched report stays here until a look finds its node gone REPORT_GRAPH_LAG_S after the
    report came (ROS learns node names from a topic of its own, so a fresh report can come
    before its sender's name). Processes that share a node name count with their newest reports,
    as many as the graph shows such publishers (each recorder reports at its start). Left open: a
    recorder restarted under a departed one's name, until its first report arrives."""

    def __init__(self, node: Node):
        self.node = node
        self.reports: dict[str, Report] = {}  # recorder id -> its latest report, oldest first
        self.subscription = node.create_subscription(String, topics.RECORDER_MATCHES, self._on_report,
                                                     qos.reliable(100, latched=True))

    def _on_report(self, msg: String) -> None:
        try:
            report = json.loads(msg.data)
            recorder = str(report["recorder"])
            matched = {str(t): int(n) for t, n in report["publishers"].items()}
        except (ValueError, KeyError, TypeError, AttributeError):
            self.node.get_logger().warning(f"malformed report on {topics.RECORDER_MATCHES}: {msg.data[:80]!r}",
                                           throttle_duration_sec=10.0)
            return
        self.reports.pop(recorder, None)  # re-inserted last: the dict runs from oldest to newest
        self.reports[recorder] = Report(recorder.split("#", 1)[0], matched, time.monotonic())

    def live(self) -> list[dict[str, int]]:
        """What each recorder in the graph reports (topic -> publishers matched); one look at
        the graph, so a caller checking many topics asks once."""
        senders = Counter(qualified_name(i.node_namespace, i.node_name)
                          for i in self.node.get_publishers_info_by_topic(self.subscription.topic_name))
        settled = time.monotonic() - REPORT_GRAPH_LAG_S
        self.reports = {r: report for r, report in self.reports.items()
                        if senders[report.node] or report.received >= settled}
        current = []
        for report in reversed(self.reports.values()):
            if senders[report.node] > 0:
                senders[report.node] -= 1
                current.append(report.matched)
        return current


def qualified_name(namespace: str, name: str) -> str:
    """A node's fully qualified name, as ``Node.get_fully_qualified_name`` writes it."""
    return f"{namespace.rstrip('/')}/{name}"


def recorders_matched(node: Node, publishers, expected: int, reports: RecorderReports) -> bool:
    """True when at least ``expected`` recorders record the topic of every publisher in
    ``publishers`` (rclpy publishers): the publisher has matched every subscription the graph
    shows there, and as many recorders in the graph report that their reader has matched every
    publisher the graph shows on that topic (so nothing published from now on is lost to
    discovery)."""
    live = None
    for publisher in publishers:
        infos = node.get_subscriptions_info_by_topic(publisher.topic_name)
        recorders = sum(i.node_name == RECORDER_NODE for i in infos)
        if recorders < expected or publisher.get_subscription_count() < len(infos):
            return False
        if expected:
            live = reports.live() if live is None else live
            if not recorders_hear(node, publisher.topic_name, expected, live):
                return False
    return True


def recorders_hear(node: Node, topic: str, expected: int, live: list[dict[str, int]]) -> bool:
    """Whether ``expected`` recorders report (``live``: :meth:`RecorderReports.live`) that their
    reader of ``topic`` has matched every publisher the graph shows there (at least one)."""
    needed = max(1, node.count_publishers(topic))
    return sum(matched.get(topic, 0) >= needed for matched in live) >= expected


def wait_for_recorders(node: Node, executor, publishers, expected: int, reports: RecorderReports,
                       timeout_s: float) -> bool:
    """Spin until ``expected`` recorders have matched every publisher (False: timed out)."""
    deadline = time.monotonic() + timeout_s
    while not recorders_matched(node, publishers, expected, reports):
        if time.monotonic() > deadline:
            return False
        executor.spin_once(timeout_sec=0.05)
    return True


def publishers_of(node: Node, topic: str) -> list[str]:
    """The fully qualified names of the nodes the graph shows publishing on ``topic`` (a full
    name): who a node waits for, named in its diagnostics."""
    return sorted({qualified_name(i.node_namespace, i.node_name) for i in node.get_publishers_info_by_topic(topic)})


def subscribers_of(node: Node, topic: str) -> list[str]:
    """The fully qualified names of the nodes the graph shows subscribing to ``topic``."""
    return sorted({qualified_name(i.node_namespace, i.node_name) for i in node.get_subscriptions_info_by_topic(topic)})
