"""Policy names on the command line -> policy objects, team assignments like
``formic:0-31,csaf11:32-63``, and the world settings a policy needs for its run."""

from __future__ import annotations

import dataclasses
from collections.abc import Iterable
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from .policy import CentralPolicy, Policy

if TYPE_CHECKING:
    from formic_world import Scenario

# Names never contain ':' (team specs are NAME:RANGES).
POLICY_NAMES = ("formic", "random", "csaf", "csaf11", "csaf-ref", "csaf11-ref", "cardinality", "planner")
DEFAULT_MODEL = Path(__file__).resolve().parents[2] / "models" / "formic_cpu.pt"

# The world settings (WorldConfig fields) a policy's run needs, over the scenario's own: the
# reference variants of C-SAF run as the authors' code did (formic_baselines.csaf docstring).
# Every run that builds its world from a scenario for a team applies them
# (apply_world_overrides): formic sim, formic eval, formic run.
_REFERENCE_CODE_WORLD = {"queue_len": 1, "agent_order": "id"}
POLICY_WORLD_OVERRIDES: dict[str, dict[str, Any]] = {
    "csaf-ref": _REFERENCE_CODE_WORLD,
    "csaf11-ref": _REFERENCE_CODE_WORLD,
}


def world_overrides(policy_names: Iterable[str]) -> dict[str, Any]:
    """The world settings a team of these policies needs (empty: the scenario's own). Every
    policy in a team must need the same ones: a policy with none needs the scenario's world,
    so mixing ``csaf11-ref`` (one-slot queues) with ``formic`` raises ValueError."""
    names = list(dict.fromkeys(policy_names))
    wanted = {name: POLICY_WORLD_OVERRIDES.get(name, {}) for name in names}
    distinct = {tuple(sorted(v.items())) for v in wanted.values()}
    if len(distinct) > 1:
        needs = "; ".join(
            f"{name} needs " + (", ".join(f"{k}={v!r}" for k, v in o.items()) or "the scenario's own world")
            for name, o in wanted.items()
        )
        raise ValueError(f"these policies cannot share one world ({needs}): run them separately")
    return dict(next(iter(wanted.values()), {}))


def apply_world_overrides(scenario: Scenario, policy_names: Iterable[str]) -> Scenario:
    """``scenario`` with the world settings these policies need (itself when there are none);
    the result is validated like a loaded scenario."""
    from formic_world.scenario import validate_scenario

    overrides = world_overrides(policy_names)
    if not overrides:
        return scenario
    config = scenario.config.replace(**overrides)
    if config == scenario.config:
        return scenario
    changed = dataclasses.replace(scenario, config=config)
    validate_scenario(changed)
    return changed


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
    if name in ("csaf-ref", "csaf11-ref"):  # the world settings: POLICY_WORLD_OVERRIDES
        from formic_baselines.csaf import CSAF11Policy, CSAFPolicy

        return CSAFPolicy(view=3, reference=True) if name == "csaf-ref" else CSAF11Policy(reference=True)
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
