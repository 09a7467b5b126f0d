"""Policy names on the command line -> policy objects, and team assignments like
``formic:0-31,csaf11:32-63``."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .policy import CentralPolicy, Policy

POLICY_NAMES = ("formic", "random", "csaf", "csaf11", "cardinality", "planner")
DEFAULT_MODEL = Path(__file__).resolve().parents[2] / "models" / "formic_cpu.pt"


def make_policy(name: str, model: str | Path | None = None, greedy: bool = False) -> Policy | CentralPolicy:
    """A fresh policy object for ``name`` (the learned one loads ``model`` or the shipped one)."""
    if name == "random":
        from formic_baselines.random_policy import RandomPolicy

        return RandomPolicy()
    if name == "csaf":
        from formic_baselines.csaf import CSAFPolicy

        return CSAFPolicy(view=3)
    if name == "csaf11":
        from formic_baselines.csaf import CSAF11Policy

        return CSAF11Policy()
    if name == "cardinality":
        from formic_baselines.cardinality import CardinalityPolicy

        return CardinalityPolicy()
    if name == "planner":
        from formic_baselines.planner import CentralizedPlanner

        return CentralizedPlanner()
    if name == "formic":
        from .learned import LearnedPolicy

        path = Path(model) if model else DEFAULT_MODEL
        if not path.exists():
            raise FileNotFoundError(
                f"no model at {path}: train one with `formic train` or pass --model"
            )
        return LearnedPolicy.from_checkpoint(path, greedy=greedy)
    raise ValueError(f"unknown policy {name!r}; choose from {', '.join(POLICY_NAMES)}")


@dataclass(frozen=True)
class TeamAssignment:
    """Which policy drives which agents; agents in ``external`` are driven from outside."""

    groups: tuple[tuple[str, tuple[int, ...]], ...]
    external: tuple[int, ...] = ()

    def policy_of(self, agent: int) -> str | None:
        for name, ids in self.groups:
            if agent in ids:
                return name
        return None

    def describe(self) -> str:
        parts = [f"{name}:{_ranges(ids)}" for name, ids in self.groups]
        if self.external:
            parts.append(f"external:{_ranges(self.external)}")
        return ",".join(parts)


def parse_team(spec: str, n_agents: int, external: tuple[int, ...] = ()) -> TeamAssignment:
    """Parse ``NAME`` or ``NAME:a-b,NAME:c,...``; every agent gets exactly one driver."""
    owner: dict[int, str] = {a: "external" for a in external}
    for a in external:
        if not 0 <= a < n_agents:
            raise ValueError(f"external agent {a} is not in 0-{n_agents - 1}")
    parts = [p.strip() for p in spec.split(",") if p.strip()]
    if not parts:
        raise ValueError("empty policy specification")
    groups: dict[str, list[int]] = {}
    for part in parts:
        name, _, rng = part.partition(":")
        if name not in POLICY_NAMES:
            raise ValueError(f"unknown policy {name!r}; choose from {', '.join(POLICY_NAMES)}")
        ids = _parse_ids(rng, n_agents) if rng else [a for a in range(n_agents) if a not in owner]
        for a in ids:
            if a in owner:
                raise ValueError(f"agent {a} is assigned twice ({owner[a]} and {name})")
            owner[a] = name
            groups.setdefault(name, []).append(a)
    missing = [a for a in range(n_agents) if a not in owner]
    if missing:
        raise ValueError(f"agents {_ranges(missing)} have no policy")
    if "planner" in groups and len(groups) > 1:
        raise ValueError("the centralized planner drives the whole team; do not mix it")
    return TeamAssignment(tuple((k, tuple(v)) for k, v in groups.items()), tuple(external))


def _parse_ids(text: str, n_agents: int) -> list[int]:
    ids: list[int] = []
    for chunk in text.split("+"):
        lo, _, hi = chunk.partition("-")
        try:
            a, b = int(lo), int(hi) if hi else int(lo)
        except ValueError as exc:
            raise ValueError(f"bad agent range {chunk!r}") from exc
        if not 0 <= a <= b < n_agents:
            raise ValueError(f"agent range {chunk!r} is outside 0-{n_agents - 1}")
        ids.extend(range(a, b + 1))
    return ids


def _ranges(ids) -> str:
    ids = sorted(ids)
    out, start = [], None
    for i, a in enumerate(ids):
        if start is None:
            start = a
        if i + 1 == len(ids) or ids[i + 1] != a + 1:
            out.append(f"{start}-{a}" if a != start else f"{a}")
            start = None
    return "+".join(out)


def team_arrays(team: TeamAssignment) -> dict[str, np.ndarray]:
    return {name: np.array(ids, dtype=np.int64) for name, ids in team.groups}
