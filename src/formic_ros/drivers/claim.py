"""A driver node's side of agent ownership (the rules: :mod:`formic_ros.world.claims`;
docs/ros.md, "Who may drive an agent"): the latched claim on ``claims``, the world's answer on
``owners``, and whether the driver may answer yet."""

from __future__ import annotations

import json
import os
import time
import uuid

import numpy as np
from std_msgs.msg import String

import formic_topics as topics

from .. import qos
from ..graph import RecorderReports, recorders_matched

READY_CHECK_S = 0.05  # a driver re-reads the graph at most this often while it waits for recorders
RECORDER_WAIT_S = 10.0  # a driver answers anyway this long after the confirmation (warned)


class Claim:
    """A driver node's claim: published (latched) at once; ``refused`` holds the agents the
    world gave to someone else (logged as an ERROR; ``on_refused`` is told). ``publishers``:
    the driver's action publishers, which the recorders must match before :meth:`ready`."""

    def __init__(self, node, agents, actions_topic: str | None = None, on_refused=None, publishers=()):
        self.node, self.agents = node, sorted(int(a) for a in agents)
        self.token = f"{node.get_fully_qualified_name()}#{os.getpid()}-{uuid.uuid4().hex[:8]}"
        self.refused: list[int] = []
        self.why_refused: str | None = None  # the world's reason, when it refused the whole claim
        self.on_refused = on_refused
        self.publishers = list(publishers)
        self.confirmed_at: float | None = None  # when the world first bound an agent to this claim
        self.recorders = 0  # how many recorders the world waits for (from ``owners``)
        self.recorder_reports = RecorderReports(node)
        self._ready, self._checked_at = False, -np.inf
        self.publisher = node.create_publisher(String, topics.CLAIMS, qos.LATCHED)
        self.publisher.publish(String(data=json.dumps({"owner": node.get_fully_qualified_name(), "token": self.token,
                                                       "agents": self.agents, "actions": actions_topic})))
        node.create_subscription(String, topics.OWNERS, self._on_owners, qos.LATCHED)

    def _on_owners(self, msg: String) -> None:
        owners_msg = json.loads(msg.data)
        owners = owners_msg.get("owners", {})
        self.recorders = int(owners_msg.get("recorders", 0))
        why = owners_msg.get("refused", {}).get(self.token)
        if why and why != self.why_refused:
            self.node.get_logger().error(f"the world refused this node's claim: {why}")
        self.why_refused = why
        if self.confirmed_at is None and self.token in owners.values():
            self.confirmed_at = time.monotonic()
        refused = [a for a in self.agents if owners.get(str(a), self.token) != self.token]
        if refused and refused != self.refused:
            self.node.get_logger().error(f"agents {refused} are driven by another node "
                                         f"({sorted({owners[str(a)] for a in refused})}); not driving them")
        self.refused = refused
        if self.on_refused is not None:
            self.on_refused(refused)

    def ready(self) -> bool:
        """Whether the driver may answer: the world confirmed the claim, and the world and the
        recorders it waits for have matched every action publisher (after ``RECORDER_WAIT_S`` it
        answers anyway, warned)."""
        now = time.monotonic()
        if self._ready or self.confirmed_at is None or now - self._checked_at < READY_CHECK_S:
            return self._ready
        self._checked_at = now
        self._ready = (all(p.get_subscription_count() for p in self.publishers)  # the world hears us
                       and recorders_matched(self.node, self.publishers, self.recorders, self.recorder_reports))
        if not self._ready and now - self.confirmed_at > RECORDER_WAIT_S:
            self.node.get_logger().warning(f"the recorder has not matched this node's action topics after "
                                           f"{RECORDER_WAIT_S:g} s: answering anyway (the recording misses them)")
            self._ready = True
        return self._ready
