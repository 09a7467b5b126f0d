"""Who owns which agent: the world's bookkeeping of driver claims (the rules for users:
docs/ros.md, "Who may drive an agent"; the messages: docs/interfaces.md, "Claims and owners").

A driver node that drives several agents (agent host, planner, learning host) publishes a latched
claim on ``claims`` (JSON ``{"owner": fully qualified node name, "token": unique per claim,
"agents": [...], "actions": its own batch topic or null}``) and answers only once
:meth:`Claim.ready` (:mod:`formic_ros.drivers.claim`). :class:`Claims` binds each unowned agent to
the first claim, confirms on ``owners`` (latched JSON ``{"owners": {agent: token}, "recorders":
how many the drivers wait for, "refused": {token: why}}``), refuses a second claim for an owned
agent unless the first owner has left the graph, and refuses claims for a run's own agents from
nodes the run did not start. Checking each message against these owners is
:mod:`formic_ros.world.ownership`'s part.
"""

from __future__ import annotations

import json
import time
from collections import Counter

from formic_interfaces.msg import ActionBatch
from std_msgs.msg import String

from formic_runtime.team import format_ids
import formic_topics as topics

from .. import qos

RECHECK_S = 0.5  # refused claims are re-examined this often (has the first owner left?)
TAKEOVER_GRACE_S = 2.0  # a claim this young is never taken over: its node may not be in the graph yet


class Claims:
    """Claims in, owners out. ``external``: the agents nodes other than the run's drivers may
    drive (None: any, as in a world started on its own); ``drivers``: the fully qualified names
    of the driver nodes the run started, the only ones whose claims for the other agents count
    (None: anyone's)."""

    def __init__(self, node, offer_batch, subscribe, external: tuple[int, ...] | None = None,
                 drivers: tuple[str, ...] | None = None):
        self.node, self.offer_batch = node, offer_batch  # offer_batch(msg, topic): into the inbox
        self.subscribe = subscribe  # subscribe(type, topic, qos, callback): malformed samples counted
        self.external = None if external is None else frozenset(int(a) for a in external)
        self.drivers = None if drivers is None else tuple(drivers)
        self.claims: dict[str, dict] = {}  # token -> claim
        self.owner_of: dict[int, str] = {}  # agent -> token
        self.refused: dict[str, dict] = {}  # token -> refused claim (re-examined)
        self.outsiders: dict[str, dict] = {}  # token -> claim refused for good, with its "why" (told on owners)
        self.batch_topics: set[str] = set()  # the owners' own batch topics (subscribed)
        self.rejected = Counter()  # the episode's rejection counter (the inbox's, from :meth:`count_into`)
        self.recorders = 0  # recorders the world waits for: drivers wait for them too
        self.told: set[tuple[str, str]] = set()  # (reason, source): logged once
        self.namespace = node.get_namespace().rstrip("/")
        subscribe(String, topics.CLAIMS, qos.reliable(1000, latched=True), self._on_claim)
        self.owners_pub = node.create_publisher(String, topics.OWNERS, qos.LATCHED)
        node.create_timer(RECHECK_S, self._recheck)

    def count_into(self, rejected: Counter) -> None:
        """Count this episode's refused claims and actions in ``rejected`` (the inbox's counter)."""
        self.rejected = rejected

    def _owners_changed(self) -> None:
        """Called before owners may change: :class:`~formic_ros.world.ownership.Ownership` drops
        what it cached from the old owners."""

    def _on_claim(self, msg: String) -> None:
        try:
            c = json.loads(msg.data)
            claim = {"owner": str(c["owner"]), "token": str(c["token"]), "agents": [int(a) for a in c["agents"]],
                     "actions": c.get("actions") and str(c["actions"])}
        except (ValueError, KeyError, TypeError):
            self._count("malformed", 1, f"{topics.CLAIMS}: {msg.data[:80]!r}", "malformed claim")
            return
        if claim["token"] in self.claims or claim["token"] in self.outsiders:
            return
        if why := self._outsider(claim):
            self.node.get_logger().error(f"claim refused: {why}")
            self.outsiders[claim["token"]] = {**claim, "why": why}
            self._publish_owners()
            return
        claim["received_at"] = time.monotonic()
        self.claims[claim["token"]] = claim
        if claim["actions"] and claim["actions"] not in self.batch_topics:
            topic = claim["actions"]
            self.batch_topics.add(topic)
            self.subscribe(ActionBatch, topic, qos.STREAM, lambda m, t=topic: self.offer_batch(m, t))
        self._bind(claim)

    def unheard_claimants(self) -> set[str]:
        """The nodes in the graph with a claims publisher whose claim has not arrived yet (a
        latched claim reaches a reader some time after its node is discovered)."""
        heard = {c["owner"] for c in (*self.claims.values(), *self.outsiders.values())}
        present = {f"{info.node_namespace.rstrip('/')}/{info.node_name}"
                   for info in self.node.get_publishers_info_by_topic(topics.full_name(self.namespace or "/",
                                                                                        topics.CLAIMS))}
        return present - heard

    def _outsider(self, claim: dict) -> str | None:
        """Why a claim may not count (None: it may): a node the run did not start claims agents
        the run's own drivers are to drive (say, a stray node that claims before the hosts start)."""
        if self.drivers is None or claim["owner"] in self.drivers:
            return None
        theirs = [a for a in claim["agents"] if a not in (self.external or ())]
        if not theirs:
            return None
        drivers = ", ".join(self.drivers) or "none"
        external = format_ids(sorted(self.external)) if self.external else "none"
        return (f"{claim['owner']} claims agents {format_ids(theirs)}, which this run's own drivers ({drivers}) "
                f"drive (--external: {external})")

    def _alive(self, owner: str) -> int:
        return sum(f"{ns.rstrip('/')}/{name}" == owner for name, ns in self.node.get_node_names_and_namespaces())

    def _bind(self, claim: dict) -> None:
        self._owners_changed()
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
                drivers = sorted({self.claims[self.owner_of[a]]["owner"] for a in taken})
                self.node.get_logger().error(
                    f"{claim['owner']} claims agents {taken}, already driven by {drivers}: "
                    "claim refused, first owner kept")
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
        self.owners_pub.publish(String(data=json.dumps({"owners": owners, "recorders": self.recorders,
                                                        "refused": {t: c["why"] for t, c in self.outsiders.items()}})))

    def _recheck(self) -> None:
        for claim in list(self.refused.values()):
            if self._alive(claim["owner"]):
                self._bind(claim)

    def why_nobody_answered(self) -> str | None:
        """What the world knows about drivers it turned away or that claimed agents and stayed
        silent (for the "nobody joined" error), or None when no driver claimed anything (then
        discovery is the likely cause)."""
        reasons = [f"refused a claim: {claim['why']}" for claim in self.outsiders.values()]
        reasons += [f"refused {claim['owner']}'s claim: its agents were already driven"
                    for claim in self.refused.values()]
        silent = {claim["owner"] for claim in self.claims.values()} - {c["owner"] for c in self.refused.values()}
        reasons += [f"{owner} claimed agents but did not answer"
                    + ("" if self._alive(owner) else " (it has left the graph)") for owner in sorted(silent)]
        rejected = {reason: n for reason, n in self.rejected.items() if n}
        if rejected:
            reasons.append("rejected actions: " + ", ".join(f"{n} {reason}" for reason, n in sorted(rejected.items())))
        return "; ".join(reasons) or None

    def _count(self, reason: str, count: int, source: str, what: str = "rejected action") -> None:
        if count:
            self.rejected[reason] += count
        key = (reason, source.split(" (")[0])
        if key not in self.told:
            self.told.add(key)
            self.node.get_logger().warning(f"{what} ({reason}): {source} (logged once, counted in the summary)")

