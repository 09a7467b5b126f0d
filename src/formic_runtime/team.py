"""A team: which policy drives which agents (``formic:0-31,csaf11:32-63``), how the team is
split across agent hosts, and acting for it on a batch of agents."""

from __future__ import annotations

import itertools
import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from formic_agent.policy import AgentBatch, CentralPolicy, Policy
from formic_world.limits import MAX_AGENTS

from .registry import check_name, make_policy, policy_class


def parse_ids(text: str, n_agents: int | None = None) -> list[int]:
    """``0-31``, ``3``, ``0-3+8-11`` or ``0,2,5`` -> sorted agent ids (all below ``n_agents``
    when it is given)."""
    ids: set[int] = set()
    for chunk in text.replace("+", ",").split(","):
        chunk = chunk.strip()
        if not chunk:
            continue
        lo, _, hi = chunk.partition("-")
        try:
            a, b = int(lo), int(hi) if hi else int(lo)
        except ValueError as exc:
            raise ValueError(f"bad agent range {chunk!r}") from exc
        if not 0 <= a <= b:
            raise ValueError(f"bad agent range {chunk!r}")
        limit = MAX_AGENTS if n_agents is None else n_agents  # checked before the range is built
        if b >= limit:
            raise ValueError(f"agent range {chunk!r} is outside 0-{limit - 1}")
        ids.update(range(a, b + 1))
    if not ids:
        raise ValueError(f"no agent ids in {text!r}")
    return sorted(ids)


def format_ids(ids) -> str:
    """The inverse of :func:`parse_ids`: ``0-3+8``."""
    # consecutive ids keep (id - position) constant: one run each
    by_run = itertools.groupby(enumerate(sorted(ids)), lambda pair: pair[1] - pair[0])
    runs = [[a for _, a in run] for _, run in by_run]
    return "+".join(f"{run[0]}-{run[-1]}" if len(run) > 1 else f"{run[0]}" for run in runs)


def _parts(spec: str) -> list[tuple[str, str]]:
    parts = [p.strip() for p in spec.split(",") if p.strip()]
    if not parts:
        raise ValueError("empty policy specification")
    out = []
    for part in parts:
        name, _, ranges = part.partition(":")
        check_name(name)
        out.append((name, ranges))
    return out


@dataclass
class Team:
    """Which policy drives which agents (global ids); agents in ``external`` are driven from
    outside. :meth:`build` makes the policies, :meth:`act` runs them."""

    groups: tuple[tuple[str, tuple[int, ...]], ...]
    external: tuple[int, ...] = ()
    members: list[tuple[Policy | CentralPolicy, np.ndarray]] = field(default_factory=list, compare=False, repr=False)

    # ------------------------------------------------------------------ the spec
    @classmethod
    def parse(cls, spec: str, n_agents: int, external: tuple[int, ...] = ()) -> Team:
        """Parse ``NAME`` or ``NAME:a-b,NAME:c,...``; every agent gets exactly one driver."""
        owner: dict[int, str] = {a: "external" for a in external}
        for a in external:
            if not 0 <= a < n_agents:
                raise ValueError(f"external agent {a} is not in 0-{n_agents - 1}")
        groups: dict[str, list[int]] = {}
        for name, ranges in _parts(spec):
            ids = parse_ids(ranges, n_agents) if ranges else [a for a in range(n_agents) if a not in owner]
            for a in ids:
                if a in owner:
                    raise ValueError(f"agent {a} is assigned twice ({owner[a]} and {name})")
                owner[a] = name
                groups.setdefault(name, []).append(a)
        missing = [a for a in range(n_agents) if a not in owner]
        if missing:
            raise ValueError(f"agents {format_ids(missing)} have no policy")
        if "planner" in groups and len(groups) > 1:
            raise ValueError("the centralized planner drives the whole team; do not mix it")
        return cls(tuple((k, tuple(v)) for k, v in groups.items()), tuple(external))

    @classmethod
    def for_agents(cls, spec: str, agent_ids: list[int]) -> Team:
        """The part of a team spec (global ids, as ``formic run --policy``) that drives these
        agents (an agent host's); a part without a range drives every agent no other part names."""
        owner: dict[int, str] = {}
        default = None
        for name, ranges in _parts(spec):
            if name == "planner":
                raise ValueError("the centralized planner is a node of its own: run `formic planner`")
            if not ranges:
                default = name
                continue
            for a in parse_ids(ranges):
                owner.setdefault(a, name)
        groups: dict[str, list[int]] = {}
        for a in agent_ids:
            name = owner.get(a, default)
            if name is None:
                raise ValueError(f"agent {a} has no policy in {spec!r}")
            groups.setdefault(name, []).append(int(a))
        return cls(tuple((k, tuple(v)) for k, v in groups.items()))

    @property
    def names(self) -> list[str]:
        return [name for name, _ in self.groups]

    def describe(self) -> str:
        parts = [f"{name}:{format_ids(ids)}" for name, ids in self.groups]
        if self.external:
            parts.append(f"external:{format_ids(self.external)}")
        return ",".join(parts)

    def split(self, hosts: int) -> list[list[int]]:
        """Agents of each host: a group whose policy shares one memory across the team stays
        whole in one host; the other agents are dealt in contiguous chunks so hosts end up
        about equally loaded."""
        if hosts <= 1:  # (without asking the policies: the learned one's class would load torch here)
            every = sorted(a for _, ids in self.groups for a in ids)
            return [every] if every else []
        buckets: list[list[int]] = [[] for _ in range(hosts)]
        splittable: list[int] = []
        for name, ids in self.groups:
            if policy_class(name).shares_team_memory:
                min(buckets, key=len).extend(ids)
            else:
                splittable.extend(ids)
        splittable.sort()
        target = math.ceil((sum(map(len, buckets)) + len(splittable)) / len(buckets))
        start = 0
        for bucket in buckets:
            take = max(0, target - len(bucket))
            bucket.extend(splittable[start:start + take])
            start += take
        buckets[-1].extend(splittable[start:])
        return [sorted(b) for b in buckets if b]

    # ---------------------------------------------------------------- the policies
    def build(self, model: str | Path | None = None, greedy: bool = False) -> Team:
        """Make each group's policy (itself, for chaining)."""
        self.members = [(make_policy(name, model=model, greedy=greedy), np.array(ids, dtype=np.int64))
                        for name, ids in self.groups]
        return self

    def reset(self, n_agents: int, seed: int) -> None:
        for policy, _ in self.members:
            policy.reset(n_agents, seed)

    def wipe(self) -> None:
        for policy, _ in self.members:
            policy.wipe()

    def act(self, batch: AgentBatch, world=None) -> np.ndarray:
        """Actions for every row of ``batch``: each group's policy acts on its rows (a
        central policy reads ``world`` and answers for every agent)."""
        actions = np.zeros(len(batch), dtype=np.int64)
        for policy, ids in self.members:
            if isinstance(policy, CentralPolicy):
                actions[:] = policy.act_world(world)
                continue
            rows = np.flatnonzero(np.isin(batch.agent_ids, ids))
            if len(rows):  # one policy for every row: the batch itself, no copy
                actions[rows] = policy.act(batch if len(rows) == len(batch) else batch.select(rows))
        return actions
