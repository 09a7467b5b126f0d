"""Who may drive an agent: each message is checked against its agent's owner (the rules for
users: docs/ros.md, "Who may drive an agent"; the claims that make owners:
:mod:`formic_ros.world.claims`).

A node that is ``agent_K`` and publishes on ``agent_K/action`` needs no claim: it owns agent K
when K is left to other nodes (``--external``; any unclaimed agent in a world started on its
own), as soon as it is that topic's only publisher. The world (:class:`Ownership`) checks every
action against its agent's owner. rclpy tells no publisher apart on one topic, so while a second
node publishes on an owned agent's topic that agent's actions are not applied (it waits, it is
not hijacked). This guards against mistakes and stray nodes, not against a node that
deliberately publishes on an owner's topic. A robot's statuses (``agent_K/robot_status``) follow
the same rule (:meth:`Ownership.status_allowed`): the first bridge seen publishing them keeps the
robot, and a second publisher halts it.
"""

from __future__ import annotations

import time
from collections import Counter

import numpy as np

import formic_topics as topics

from ..graph import RecorderReports, qualified_name, recorders_hear
from .claims import Claims

GRAPH_REFRESH_S = 2.0  # a per-agent topic's publishers are re-read at most this often
UNKNOWN_NODE = "_NODE_NAME_UNKNOWN_"  # the graph's name for a publisher whose node it has not discovered yet
RECORDER_PENDING = {"owner": "", "token": "", "agents": [], "actions": None}  # an adoption waiting for recorders


class Ownership(Claims):
    """The world's side: :class:`Claims`' owners, and :meth:`allowed` / :meth:`allowed_batch`
    (the inbox's gate) and :meth:`status_allowed` (robot statuses). ``agent_readers``: the world's
    reader of each per-agent action topic (full name -> rclpy subscription: its matched-publisher
    count is a local call, cheap enough for every action); ``external``, ``drivers``: as for
    :class:`Claims`."""

    def __init__(self, node, offer_batch, subscribe, agent_readers: dict | None = None,
                 external: tuple[int, ...] | None = None, drivers: tuple[str, ...] | None = None,
                 recorder_reports: RecorderReports | None = None):
        self.recorder_reports = recorder_reports  # what the recorders hear (None: nothing waits for them)
        self.agent_readers = agent_readers or {}
        self.graph: dict[str, tuple[float, list[str]]] = {}  # topic -> (read at, publisher node names)
        self.trusted: dict[tuple[str, int], float] = {}  # (topic, agent) -> allowed until (monotonic s)
        self.batch_agents: dict[str, np.ndarray] = {}  # an owner's batch topic -> the agents it drives
        self.status_owners: dict[str, str] = {}  # a robot's status topic -> the bridge node that keeps it
        super().__init__(node, offer_batch, subscribe, external, drivers)

    def _owners_changed(self) -> None:
        self.trusted.clear()  # owners may change here: every source is checked again
        self.batch_agents.clear()

    def _adopt(self, agent: int, via: str) -> dict | None:
        """The claim a node that is ``agent_K`` needs none of: it owns agent K, when K is left to
        other nodes, as soon as it is the only publisher on ``agent_K/action`` (None: it is not)
        and the recorders the world waits for hear it (``RECORDER_PENDING`` until then)."""
        node = f"{self.namespace}/{topics.agent_node_name(agent)}"
        if (self.external is not None and agent not in self.external) or via != self._action_topic(agent):
            return None
        if self._publishers(via, fresh=True) != [node]:
            return None
        if self.recorders and not recorders_hear(self.node, via, self.recorders, self.recorder_reports.live()):
            if ("unrecorded", via) not in self.told:
                self.told.add(("unrecorded", via))
                self.node.get_logger().info(f"agent {agent}: waiting for the recorder to hear {node} before taking "
                                            "its actions, so that the recording holds them all")
            return RECORDER_PENDING
        claim = {"owner": node, "token": f"{node}#node", "agents": [agent], "actions": None,
                 "received_at": time.monotonic()}
        self.claims[claim["token"]] = claim
        self.node.get_logger().info(f"agent {agent}: driven by its node {node} (no claim needed)")
        self._bind(claim)
        return claim

    def _action_topic(self, agent: int) -> str:
        return topics.full_name(self.namespace or "/", topics.agent_topic(agent, topics.AGENT_ACTION))

    def _publishers(self, topic: str, fresh: bool = False) -> list[str]:
        """The nodes publishing on ``topic`` (sorted, one entry per publisher), from the graph
        read at most ``GRAPH_REFRESH_S`` ago unless ``fresh``."""
        read_at, names = self.graph.get(topic, (-np.inf, []))
        if fresh or time.monotonic() - read_at > GRAPH_REFRESH_S:
            infos = self.node.get_publishers_info_by_topic(topic)
            names = sorted(qualified_name(i.node_namespace, i.node_name) for i in infos)
            self.graph[topic] = (time.monotonic(), names)
        return names

    def _drives(self, claim: dict, agent: int, via: str) -> bool:
        if claim["actions"]:
            return via == claim["actions"]
        if via != self._action_topic(agent):
            return False
        node = f"{self.namespace}/{topics.agent_node_name(agent)}"
        return node in self._publishers(via) or node in self._publishers(via, fresh=True)  # perhaps just discovered

    def _shared(self, via: str, agent: int) -> bool:
        """Whether another node publishes on agent ``agent``'s own action topic beside its
        owner: rclpy cannot tell their messages apart, so none is applied while it does (the
        agent waits; counted as ``foreign publisher``, an ERROR once per topic). The nodes whose
        claims for the agent the world refused were told so and stand down: they are allowed."""
        reader = self.agent_readers.get(via)
        if reader is None or reader.get_publisher_count() <= 1:  # the common case, checked on every action
            return False
        refused = (*self.refused.values(), *self.outsiders.values())
        told = sum(agent in c["agents"] and not c["actions"] for c in refused)
        if reader.get_publisher_count() <= 1 + told:
            return False
        owner = self.claims[self.owner_of[agent]]["owner"]
        self._halt(self.rejected, via, reader.get_publisher_count(), f"agent {agent} is driven by {owner}",
                   "its actions are not applied while another node publishes there (the first owner keeps the "
                   "agent, which waits; stop the other node)")
        return True

    def _halt(self, rejected: Counter, via: str, count: int, owned: str, effect: str) -> None:
        """A second node publishes on an owned topic: counted as ``foreign publisher`` in
        ``rejected``, with one ERROR per topic naming the owner and every node on the topic (once
        the graph names them all)."""
        rejected["foreign publisher"] += 1
        if ("foreign publisher", via) not in self.told:
            names = [n for n in self._publishers(via, fresh=True) if UNKNOWN_NODE not in n]
            if len(names) < count:  # the graph has not named every publisher yet: tell it once it has
                return
            self.told.add(("foreign publisher", via))
            self.node.get_logger().error(
                f"{owned}, but {count} publishers are on {via} (nodes {', '.join(names)}): {effect}. "
                "Logged once, counted in the summary")

    def status_allowed(self, robot: int, reader, rejected: Counter) -> bool:
        """Whether a status on robot ``robot``'s status topic (``reader``: the world's subscription)
        comes from the bridge that owns the robot: its bridge node ``robot_bridge_K`` if present
        when the first status comes, else the first node seen publishing there. While
        another node publishes beside it no status is taken: the robot's moves fail and it stays
        in its cell (halted, not hijacked), counted in ``rejected``."""
        via, count = reader.topic_name, reader.get_publisher_count()
        if count <= 1 and via in self.status_owners:  # the common case, checked on every status
            return True
        names = [n for n in self._publishers(via, fresh=True) if UNKNOWN_NODE not in n]
        bridge = f"{self.namespace}/robot_bridge_{robot}"  # the name every bridge has (formic robot, formic run)
        if via not in self.status_owners and (bridge in names or len(names) == 1):
            self.status_owners[via] = bridge if bridge in names else names[0]
        if count <= 1 and len(names) <= 1 and self.status_owners.get(via) in (*names, None):
            return True
        self._halt(rejected, via, max(count, len(names)),
                   f"robot {robot}'s statuses come from its bridge {self.status_owners.get(via, '(not known yet)')}",
                   "no status of the robot is taken while another node publishes there (its moves fail: it stays "
                   "in its cell; stop the other node)")
        return False

    def allowed(self, via: str, agent: int) -> bool:
        """Whether agent ``agent``'s action that arrived on topic ``via`` was sent by its owner.
        A yes holds for ``GRAPH_REFRESH_S`` (or until the owners change): per-agent actions come
        one message each, and checking each anew cost the world ~5 ms a step at 128 agents. A
        second publisher on the owner's topic is checked on every action."""
        now = time.monotonic()
        if self.trusted.get((via, agent), -np.inf) > now:
            return not self._shared(via, agent)
        claim = self.claims.get(self.owner_of.get(agent, ""))
        if claim is None:
            claim = self._adopt(agent, via)
            if claim is RECORDER_PENDING:
                return False  # dropped, not rejected: the world re-sends the observation
        if claim is not None and self._drives(claim, agent, via):
            if self._shared(via, agent):
                return False
            self.trusted[(via, agent)] = now + GRAPH_REFRESH_S
            return True
        closed = claim is None and self.external is not None and agent not in self.external
        detail = (f"agent {agent} is not --external: only the run's own drivers drive it, and none has claimed it"
                  if closed else f"agent {agent} and maybe more")
        self._count("unclaimed" if claim is None else "not owner", 1, f"{via} ({detail})")
        return False

    def allowed_batch(self, via: str, ids: np.ndarray) -> np.ndarray:
        """:meth:`allowed` for a batch's agents at once (the agents the owner of topic ``via``
        drives are kept, sorted, until the owners change; the rest are checked, and counted, one
        by one). A binary search, not ``np.isin``: this runs on every batch, and ``np.isin`` took
        ~0.13 ms of the world's step at 128 agents."""
        owned = self.batch_agents.get(via)
        if owned is None:
            owned = self.batch_agents[via] = np.array(
                sorted(a for a, t in self.owner_of.items() if self.claims[t]["actions"] == via), dtype=np.int64)
        ok = owned.take(owned.searchsorted(ids), mode="clip") == ids if len(owned) else np.zeros(len(ids), bool)
        if not ok.all():
            ok[~ok] = [self.allowed(via, a) for a in ids[~ok].tolist()]
        return ok
