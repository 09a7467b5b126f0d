"""Recording and republishing over ROS (the files themselves are :mod:`formic_record`'s).

The recorder node writes every ForMIC topic (and ``/clock``) into a rosbag2 recording with MCAP
storage, as the CDR bytes that arrived (``raw=True``: nothing is decoded on the hot path): the
world's topics from the start and the per-agent ones once the scenario names the team, so the
world can wait for the recorder (:func:`formic_ros.graph.recorders_matched`) before it steps,
on the recorder's own report of what its readers have matched (``recorder_matches``);
anything else in the namespace once the graph shows a publisher, with the QoS it offers. The
latched scenario description becomes the recording's run description (seed, scenario,
configuration digest, policies, model checkpoint id, package version). A stop signal closes the
recording cleanly (:func:`record`); a SIGKILL leaves every chunk flushed so far readable (see
:mod:`formic_record.bag`).
"""

from __future__ import annotations

import importlib
import json
import os
import time
import uuid
from collections import Counter
from dataclasses import dataclass
from pathlib import Path

from rclpy.duration import Duration
from rclpy.event_handler import SubscriptionEventCallbacks
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
from rosbags.interfaces import Qos, QosDurability, QosHistory, QosLiveliness, QosReliability, QosTime
from std_msgs.msg import String

import formic_topics as topics
from formic_record.bag import BagWriter, package_version
from formic_record.reading import Recording

from .. import qos
from ..env import check_domain_id, ros_session
from ..graph import RECORDER_NODE, recorder_report
from ..parameters import declare_settings, settings_of
from formic_runtime.signals import stop_requests

DISCOVERY_PERIOD_S = 0.2
REPORT_PERIOD_S = 0.02  # a changed match count is reported within this long
STREAM_DEPTH = 100  # the depth recorded for (and replayed with) stream topics
DRAIN_QUIET_S, DRAIN_LIMIT_S = 0.25, 3.0  # after a stop: until no message for the first, at most the second


def message_class(msgtype: str):
    """The Python class of ``pkg/msg/Name``."""
    package, _, name = msgtype.split("/")
    return getattr(importlib.import_module(f"{package}.msg"), name)


def subscription_qos(latched: bool) -> QoSProfile:
    """Reliable and keep-all, transient-local when ``latched``. Keep all: a reader history that
    drops its oldest samples loses messages whenever this process falls behind (measured: applied
    actions lost at 1,000 steps/s); keep-all holds them until the callbacks catch up (the world's
    logs keep LOG_DEPTH for the same reason). Latched too: a depth-1 reader drops a map that a
    newer one follows quickly."""
    return QoSProfile(history=HistoryPolicy.KEEP_ALL, depth=1 if latched else STREAM_DEPTH,
                      reliability=ReliabilityPolicy.RELIABLE,
                      durability=DurabilityPolicy.TRANSIENT_LOCAL if latched else DurabilityPolicy.VOLATILE)


def adapted_qos(offered: list[QoSProfile]) -> QoSProfile:
    """What ``ros2 bag record`` does: reliable only if every publisher is, transient-local
    only if every publisher is (otherwise some would not match)."""
    latched = bool(offered) and all(p.durability == DurabilityPolicy.TRANSIENT_LOCAL for p in offered)
    profile = subscription_qos(latched)
    if not all(p.reliability == ReliabilityPolicy.RELIABLE for p in offered):
        profile.reliability = ReliabilityPolicy.BEST_EFFORT
    return profile


def _qos_time(nanoseconds: int) -> QosTime:
    return QosTime(nanoseconds // 1_000_000_000, nanoseconds % 1_000_000_000)


def to_bag_qos(profile: QoSProfile) -> Qos:
    """An rclpy QoS profile as rosbags stores it in the recording (same enum values as rmw)."""
    return Qos(
        history=QosHistory(int(profile.history)),
        depth=profile.depth,
        reliability=QosReliability(int(profile.reliability)),
        durability=QosDurability(int(profile.durability)),
        deadline=_qos_time(profile.deadline.nanoseconds),
        lifespan=_qos_time(profile.lifespan.nanoseconds),
        liveliness=QosLiveliness(int(profile.liveliness)),
        liveliness_lease_duration=_qos_time(profile.liveliness_lease_duration.nanoseconds),
        avoid_ros_namespace_conventions=profile.avoid_ros_namespace_conventions,
    )


def from_bag_qos(recorded: list[Qos]) -> QoSProfile:
    """The QoS to republish a recorded topic with (its first recorded profile; a stream
    profile when none was recorded)."""
    if not recorded:
        return subscription_qos(False)
    q = recorded[0]
    durable = q.durability == QosDurability.TRANSIENT_LOCAL
    return QoSProfile(
        history=HistoryPolicy.KEEP_LAST,
        depth=max(q.depth, 1 if durable else STREAM_DEPTH),
        reliability=(ReliabilityPolicy.BEST_EFFORT if q.reliability == QosReliability.BEST_EFFORT
                     else ReliabilityPolicy.RELIABLE),
        durability=DurabilityPolicy.TRANSIENT_LOCAL if durable else DurabilityPolicy.VOLATILE,
    )


@dataclass
class RecorderOptions:
    namespace: str = topics.DEFAULT_NAMESPACE
    topics: tuple[str, ...] = ()  # absolute names; empty: the namespace and /clock
    checkpoint_id: str = ""  # of the model the learned agents run (recorded with the run)
    chunk_bytes: int = 256 * 1024
    flush_seconds: float = 0.5


class Recorder(Node):
    """Node ``recorder`` in the namespace; writes to a :class:`BagWriter`."""

    def __init__(self, writer: BagWriter, options: RecorderOptions):
        super().__init__(RECORDER_NODE, namespace=options.namespace)
        declare_settings(self, settings_of(options) | {"out": str(writer.path)})
        self.writer = writer
        self.options = options
        self.counts: Counter = Counter()
        self.skipped: dict[str, str] = {}
        self._recorded: dict[str, object] = {}
        self.recorder_id = f"{self.get_fully_qualified_name()}#{os.getpid()}-{uuid.uuid4().hex[:8]}"
        self.report_pub = self.create_publisher(String, topics.RECORDER_MATCHES, qos.LATCHED)
        self._report_timer = self.create_timer(REPORT_PERIOD_S, self._report)  # runs only while a report is due
        run_info = {"package_version": package_version()}
        if options.checkpoint_id:
            run_info["checkpoint_id"] = options.checkpoint_id
        writer.set_run_info(run_info)
        for leaf in topics.WORLD_TOPICS:
            name, spec = topics.full_name(options.namespace, leaf), qos.TOPICS[leaf]
            if self._wanted(name):
                self._subscribe(name, spec.msgtype, subscription_qos(spec.latched))
        self._discover()
        self.create_timer(DISCOVERY_PERIOD_S, self._discover)

    def _subscribe_agents(self, scenario_json: str) -> None:
        """Every per-agent topic of the scenario's team, at once (not when it shows up in the
        graph: the world publishes an agent's observations only once a subscriber matched)."""
        try:
            n_agents = int(json.loads(scenario_json)["config"]["n_agents"])
        except (ValueError, KeyError, TypeError):
            return
        for agent in range(n_agents):
            for leaf in (topics.AGENT_OBSERVATION, topics.AGENT_ACTION):
                name = topics.full_name(self.options.namespace, topics.agent_topic(agent, leaf))
                if name not in self._recorded and name not in self.skipped and self._wanted(name):
                    self._subscribe(name, topics.TOPIC_TYPES[leaf], subscription_qos(False))

    def _wanted(self, name: str) -> bool:
        if self.options.topics:
            return name in self.options.topics
        if any(part.startswith("_") for part in name.split("/")):
            return False  # hidden topics (e.g. an action's _action/feedback), as rosbag2 leaves them out
        namespace = self.options.namespace.rstrip("/")
        if name == topics.full_name(namespace, topics.RECORDER_MATCHES):
            return False  # the recorders' own bookkeeping, not part of the run
        return name == topics.CLOCK or name.startswith(namespace + "/")

    def _discover(self) -> None:
        for name, types in self.get_topic_names_and_types():
            if name in self._recorded or name in self.skipped or not self._wanted(name):
                continue
            offered = [info.qos_profile for info in self.get_publishers_info_by_topic(name)]
            if not offered:
                continue  # only subscribers so far: wait for a publisher to learn its QoS
            self._subscribe(name, types[0], adapted_qos(offered))

    def _subscribe(self, name: str, msgtype: str, profile: QoSProfile) -> None:
        if not self.writer.knows_type(msgtype):
            self.skipped[name] = f"unknown message type {msgtype}"
            self.get_logger().warning(f"not recording {name}: {self.skipped[name]}")
            return
        try:
            cls = message_class(msgtype)
        except (ImportError, AttributeError, ValueError) as exc:
            self.skipped[name] = f"cannot import {msgtype} ({exc})"
            self.get_logger().warning(f"not recording {name}: {self.skipped[name]}")
            return
        self.writer.add_topic(name, msgtype, [to_bag_qos(profile)])
        self._recorded[name] = self.create_subscription(
            cls, name, lambda data, name=name, msgtype=msgtype: self._on_message(name, msgtype, data),
            profile, raw=True, event_callbacks=SubscriptionEventCallbacks(matched=lambda _status: self._report_soon()),
        )
        self._report_soon()

    def _report_soon(self) -> None:
        """Report within REPORT_PERIOD_S: the matches that change meanwhile (a burst of readers
        matching at start) go out in one report, and no timer runs while nothing changes."""
        if self._report_timer.is_canceled():
            self._report_timer.reset()

    def _report(self) -> None:
        """Publish what every reader has matched (reader side: a writer that counts this
        recorder as matched may not be matched by it yet)."""
        self._report_timer.cancel()
        self.report_pub.publish(recorder_report(self.recorder_id, self._recorded.values()))

    def _on_message(self, topic: str, msgtype: str, data: bytes) -> None:
        self.writer.write(topic, time.time_ns(), data)
        self.counts[topic] += 1
        if msgtype == topics.SCENARIO_TYPE:
            self._describe_run(data)

    def _describe_run(self, data: bytes) -> None:
        msg = self.writer.typestore.deserialize_cdr(data, topics.SCENARIO_TYPE)
        self._subscribe_agents(msg.scenario_json)
        self.writer.set_run_info({
            "seed": str(msg.seed),
            "scenario": msg.scenario_json,
            "config_digest": msg.config_digest,
            "policies": msg.policies,
            "scenario_format_version": str(msg.format_version),
        })


def drain(executor, node: Recorder, quiet_s: float = DRAIN_QUIET_S, limit_s: float = DRAIN_LIMIT_S) -> None:
    """Take what already arrived before the bag closes: spin until no message came for
    ``quiet_s`` (at most ``limit_s``). A recorder stopped right after the run (a launcher stops
    it once the world has left) may still hold the last steps' messages unread, most often on a
    busy machine."""
    started = quiet_from = time.monotonic()
    seen = sum(node.counts.values())
    while (now := time.monotonic()) - quiet_from < quiet_s and now - started < limit_s:
        executor.spin_once(timeout_sec=0.05)
        if (count := sum(node.counts.values())) != seen:
            seen, quiet_from = count, time.monotonic()


def record(out: str | Path, options: RecorderOptions, domain_id: int | None = None,
           duration_s: float | None = None, on_ready=None) -> dict:
    """Record until SIGINT/SIGTERM/SIGHUP (or ``duration_s``); returns counts per topic. The
    bag is closed (summary and metadata.yaml written) on every exit but a SIGKILL: from the
    first signal to the end of the close, further signals are only noted (a second Ctrl-C or
    the terminal's SIGHUP cannot cut the close short)."""
    check_domain_id(domain_id)  # before anything is written
    counts, skipped = {}, {}
    with stop_requests() as stop:
        writer = BagWriter(out, chunk_bytes=options.chunk_bytes, flush_seconds=options.flush_seconds)
        try:
            with ros_session(domain_id, interrupt=False) as executor:
                node = Recorder(writer, options)
                executor.add_node(node)
                if on_ready is not None:
                    on_ready(node)
                deadline = None if duration_s is None else time.monotonic() + duration_s
                while not stop and (deadline is None or time.monotonic() < deadline):
                    executor.spin_once(timeout_sec=0.1)
                    writer.flush_if_due()
                drain(executor, node)
                counts, skipped = dict(node.counts), dict(node.skipped)
        finally:
            writer.close()
    return {"recording": str(out), "file": str(writer.mcap_path), "messages": sum(counts.values()),
            "topics": counts, "skipped": skipped}


def republish(path: str | os.PathLike, rate: float = 1.0, domain_id: int | None = None,
              topics: tuple[str, ...] = (), wait_s: float = 1.0, log=print) -> dict:
    """Publish the recorded messages again (their CDR bytes, with their recorded types and
    QoS) on the recorded clock: a message recorded ``d`` seconds after the first is sent
    ``d / rate`` seconds after the start (``rate`` 0: as fast as possible). ``/clock`` is
    among them, so nodes with ``use_sim_time`` follow the recorded sim time. Playing starts
    once every topic has a subscriber, or after ``wait_s``."""
    recording = Recording(path)
    if recording.streamed:
        log(f"note: {recording.describe()}")
    chosen = {t: info for t, info in recording.topics.items() if not topics or t in topics}
    sent = dict.fromkeys(chosen, 0)
    with ros_session(domain_id) as executor:
        node = Node("replay")
        executor.add_node(node)
        publishers = {t: node.create_publisher(message_class(info.msgtype), t, from_bag_qos(info.qos))
                      for t, info in chosen.items()}
        wait_until = time.monotonic() + wait_s
        while time.monotonic() < wait_until and any(p.get_subscription_count() == 0 for p in publishers.values()):
            executor.spin_once(timeout_sec=0.05)
        start, first = time.monotonic(), None
        for message in recording.messages(chosen):
            first = message.log_time if first is None else first
            if rate > 0:
                delay = start + (message.log_time - first) / 1e9 / rate - time.monotonic()
                if delay > 0:
                    time.sleep(delay)
            publishers[message.topic].publish(message.data)
            sent[message.topic] += 1
        for publisher in publishers.values():
            publisher.wait_for_all_acked(Duration(seconds=2.0))
    return {"recording": str(path), "messages": sum(sent.values()), "topics": sent,
            "seconds": time.monotonic() - start}
