"""Who may drive an agent: each agent is bound to one owner, the node that claims it (the rules
for users: docs/ros.md, "Who may drive an agent").

A driver node publishes a latched claim on ``claims`` (JSON ``{"owner": fully qualified node
name, "token": unique per claim, "agents": [...], "actions": its own batch topic or null}``)
and answers only once :meth:`Claim.ready`. The world (:class:`Ownership`) binds each unowned
agent to the first claim, confirms on ``owners`` (latched JSON ``{"owners": {agent: token},
"recorders": how many the drivers wait for}``), refuses a second claim for an owned agent unless
the first owner has left the graph, and checks every action against its agent's owner. rclpy
tells no publisher apart on one topic, so this guards against mistakes and stray nodes, not
against a node that deliberately publishes on an owner's topic.
"""

from __future__ import annotations

import json
import os
import time
import uuid

import numpy as np
from formic_interfaces.msg import ActionBatch
from std_msgs.msg import String

from . import qos
from .graph import RecorderReports, qualified_name, recorders_matched
from .wire import read

GRAPH_REFRESH_S = 2.0  # a per-agent topic's publishers are re-read at most this often
RECHECK_S = 0.5  # refused claims are re-examined this often (has the first owner left?)
TAKEOVER_GRACE_S = 2.0  # a claim this young is never taken over: its node may not be in the graph yet
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
        self.on_refused = on_refused
        self.publishers = list(publishers)
        self.confirmed_at: float | None = None  # when the world first bound an agent to this claim
        self.recorders = 0  # how many recorders the world waits for (from ``owners``)
        self.recorder_reports = RecorderReports(node)
        self._ready, self._checked_at = False, -np.inf
        self.publisher = node.create_publisher(String, qos.CLAIMS, qos.LATCHED)
        self.publisher.publish(String(data=json.dumps({"owner": node.get_fully_qualified_name(), "token": self.token,
                                                       "agents": self.agents, "actions": actions_topic})))
        node.create_subscription(String, qos.OWNERS, self._on_owners, qos.LATCHED)

    def _on_owners(self, msg: String) -> None:
        owners_msg = json.loads(msg.data)
        owners = owners_msg.get("owners", {})
        self.recorders = int(owners_msg.get("recorders", 0))
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
        recorders it waits for have matched every action publisher (after ``RECORDER_WAIT_S`` it answers anyway, warned)."""
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


class Ownership:
    """The world's side: claims in, owners out, and :meth:`allowed` / :meth:`allowed_batch`
    (the inbox's gate)."""

    def __init__(self, node, offer_batch, subscribe):
        self.node, self.offer_batch = node, offer_batch  # offer_batch(msg, topic): into the inbox
        self.subscribe = subscribe  # subscribe(type, topic, qos, callback): malformed samples counted
        self.claims: dict[str, dict] = {}  # token -> claim
        self.owner_of: dict[int, str] = {}  # agent -> token
        self.refused: dict[str, dict] = {}  # token -> refused claim (re-examined)
        self.batch_topics: set[str] = set()  # the owners' own batch topics (subscribed)
        self.rejected = None  # the inbox's rejection counter (set by the world per episode)
        self.recorders = 0  # recorders the world waits for: drivers wait for them too
        self.told: set[tuple[str, str]] = set()  # (reason, source): logged once
        self.graph: dict[str, tuple[float, set[str]]] = {}  # topic -> (read at, publisher node names)
        self.trusted: dict[tuple[str, int], float] = {}  # (topic, agent) -> allowed until (monotonic s)
        self.batch_agents: dict[str, np.ndarray] = {}  # an owner's batch topic -> the agents it drives
        self.namespace = node.get_namespace().rstrip("/")
        subscribe(String, qos.CLAIMS, qos.reliable(1000, latched=True), self._on_claim)
        self.owners_pub = node.create_publisher(String, qos.OWNERS, qos.LATCHED)
        node.create_timer(RECHECK_S, self._recheck)

    # ------------------------------------------------------------------ claims
    def _on_claim(self, msg: String) -> None:
        try:
            c = json.loads(msg.data)
            claim = {"owner": str(c["owner"]), "token": str(c["token"]), "agents": [int(a) for a in c["agents"]],
                     "actions": c.get("actions") and str(c["actions"])}
        except (ValueError, KeyError, TypeError):
            self._count("malformed", 1, f"{qos.CLAIMS}: {msg.data[:80]!r}", "malformed claim")
            return
        if claim["token"] in self.claims:
            return
        claim["received_at"] = time.monotonic()
        self.claims[claim["token"]] = claim
        if claim["actions"] and claim["actions"] not in self.batch_topics:
            topic = claim["actions"]
            self.batch_topics.add(topic)
            self.subscribe(ActionBatch, topic, qos.STREAM, lambda m, t=topic: self.offer_batch(m, t))
        self._bind(claim)

    def _alive(self, owner: str) -> int:
        return sum(f"{ns.rstrip('/')}/{name}" == owner for name, ns in self.node.get_node_names_and_namespaces())

    def _bind(self, claim: dict) -> None:
        self.trusted.clear()  # owners may change here: every source is checked again
        self.batch_agents.clear()
        taken = []
        now = time.monotonic()
        for a in claim["agents"]:
            first = self.claims.get(self.owner_of.get(a, ""))
            if first is None or first["token"] == claim["token"]:
                self.owner_of[a] = claim["token"]
                continue
            same_name = first["owner"] == claim["owner"]
            # A young claim's node may not be in the graph yet. Under one name the graph cannot tell
            # a restart from a second node it has not discovered, so the newcomer waits too.
            young = now - first["received_at"] < TAKEOVER_GRACE_S or (
                same_name and now - claim["received_at"] < TAKEOVER_GRACE_S)
            if self._alive(first["owner"]) > same_name or young:
                taken.append(a)
            else:  # the first owner has left the graph: a restarted host takes over
                self.node.get_logger().info(f"agent {a}: {first['owner']} has left, {claim['owner']} drives it now")
                self.owner_of[a] = claim["token"]
        if taken:
            if claim["token"] not in self.refused:
                self.node.get_logger().error(
                    f"{claim['owner']} claims agents {taken}, already driven by "
                    f"{sorted({self.claims[self.owner_of[a]]['owner'] for a in taken})}: claim refused, first owner kept")
            self.refused[claim["token"]] = claim
        else:
            self.refused.pop(claim["token"], None)
        self._publish_owners()

    def expect_recorders(self, count: int) -> None:
        """Tell the drivers how many recorders must match their action topics before they answer."""
        if count != self.recorders:
            self.recorders = count
            self._publish_owners()

    def _publish_owners(self) -> None:
        owners = {str(a): t for a, t in self.owner_of.items()}
        self.owners_pub.publish(String(data=json.dumps({"owners": owners, "recorders": self.recorders})))

    def _recheck(self) -> None:
        for claim in list(self.refused.values()):
            if self._alive(claim["owner"]):
                self._bind(claim)

    # ------------------------------------------------------------------ actions
    def _count(self, reason: str, count: int, source: str, what: str = "rejected action") -> None:
        if self.rejected is not None and count:
            self.rejected[reason] += count
        key = (reason, source.split(" (")[0])
        if key not in self.told:
            self.told.add(key)
            self.node.get_logger().warning(f"{what} ({reason}): {source} (logged once, counted in the summary)")

    def _publishers(self, topic: str) -> set[str]:
        read_at, names = self.graph.get(topic, (-np.inf, set()))
        if time.monotonic() - read_at > GRAPH_REFRESH_S:
            infos = self.node.get_publishers_info_by_topic(topic)
            names = {qualified_name(i.node_namespace, i.node_name) for i in infos}
            self.graph[topic] = (time.monotonic(), names)
        return names

    def _drives(self, claim: dict, agent: int, via: str) -> bool:
        if claim["actions"]:
            return via == claim["actions"]
        topic = qos.full_name(self.namespace or "/", qos.agent_topic(agent, qos.AGENT_ACTION))
        if via != topic:
            return False
        node = f"{self.namespace}/{qos.agent_node_name(agent)}"
        names = self._publishers(topic)
        if node not in names:
            self.graph.pop(topic, None)  # perhaps not discovered yet: read again
            names = self._publishers(topic)
        for other in names - {node}:
            self._count("foreign publisher", 0, f"{other} publishes on {topic} too (its messages cannot be "
                        "told apart from the owner's)", "warning")
        return node in names

    def allowed(self, via: str, agent: int) -> bool:
        """Whether agent ``agent``'s action that arrived on topic ``via`` was sent by its owner.
        A yes holds for ``GRAPH_REFRESH_S`` (or until the owners change): per-agent actions come
        one message each, and checking each anew cost the world ~5 ms a step at 128 agents."""
        now = time.monotonic()
        if self.trusted.get((via, agent), -np.inf) > now:
            return True
        claim = self.claims.get(self.owner_of.get(agent, ""))
        if claim is not None and self._drives(claim, agent, via):
            self.trusted[(via, agent)] = now + GRAPH_REFRESH_S
            return True
        self._count("unclaimed" if claim is None else "not owner", 1, f"{via} (agent {agent} and maybe more)")
        return False

    def allowed_batch(self, via: str, ids: np.ndarray) -> np.ndarray:
        """:meth:`allowed` for a batch's agents at once (the agents the owner of topic ``via``
        drives are kept until the owners change; the rest are checked, and counted, one by one)."""
        owned = self.batch_agents.get(via)
        if owned is None:
            owned = self.batch_agents[via] = np.array(
                sorted(a for a, t in self.owner_of.items() if self.claims[t]["actions"] == via), dtype=np.int64)
        ok = np.isin(ids, owned)
        if not ok.all():
            ok[~ok] = [self.allowed(via, a) for a in ids[~ok].tolist()]
        return ok


def batch_of(msg: ActionBatch) -> tuple[int, np.ndarray, np.ndarray]:
    return msg.step, read(msg.agent_ids, np.uint32), read(msg.actions, np.uint8)
