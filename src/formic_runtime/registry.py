"""Policy names on the command line -> policy objects, and the world settings a policy needs
for its run."""

from __future__ import annotations

import dataclasses
import importlib
from collections.abc import Iterable
from pathlib import Path
from typing import TYPE_CHECKING, Any

from formic_world.errors import InputError

if TYPE_CHECKING:
    from formic_agent.policy import CentralPolicy, Policy
    from formic_world import Scenario

# name -> (module, class, constructor arguments). Names never contain ':' (team specs are
# NAME:RANGES).
_POLICIES: dict[str, tuple[str, str, dict[str, Any]]] = {
    "formic": ("formic_agent.learned", "LearnedPolicy", {}),
    "random": ("formic_baselines.random_policy", "RandomPolicy", {}),
    "csaf": ("formic_baselines.csaf", "CSAFPolicy", {"view": 3}),
    "csaf11": ("formic_baselines.csaf", "CSAF11Policy", {}),
    "csaf-ref": ("formic_baselines.csaf", "CSAFPolicy", {"view": 3, "reference": True}),
    "csaf11-ref": ("formic_baselines.csaf", "CSAF11Policy", {"reference": True}),
    "cardinality": ("formic_baselines.cardinality", "CardinalityPolicy", {}),
    "planner": ("formic_baselines.planner", "CentralizedPlanner", {}),
}
POLICY_NAMES = tuple(_POLICIES)
# The recipe's seed that validation chooses (issue 25; tests/test_seeds.py checks the copy).
DEFAULT_MODEL = Path(__file__).resolve().parents[2] / "models" / "formic_recipe.pt"

# The world settings (WorldConfig fields) a policy's run needs, over the scenario's own: the
# reference variants of C-SAF run as the authors' code did (docs/baselines.md).
# Every run that builds its world from a scenario for a team applies them
# (apply_world_overrides): formic sim, formic eval, formic run.
_REFERENCE_CODE_WORLD = {"queue_len": 1, "agent_order": "id"}
POLICY_WORLD_OVERRIDES: dict[str, dict[str, Any]] = {
    "csaf-ref": _REFERENCE_CODE_WORLD,
    "csaf11-ref": _REFERENCE_CODE_WORLD,
}


def check_name(name: str) -> None:
    if name not in _POLICIES:
        raise ValueError(f"unknown policy {name!r}; choose from {', '.join(POLICY_NAMES)}")


def policy_class(name: str) -> type:
    """The class behind a policy name (its capabilities without building one)."""
    check_name(name)
    module, cls, _ = _POLICIES[name]
    return getattr(importlib.import_module(module), cls)


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


def model_path(model: str | Path | None) -> Path:
    """The learned policy's checkpoint: ``model``, or the shipped one (checked without loading
    torch, so a launcher can refuse a missing model before it starts any process)."""
    path = Path(model) if model else DEFAULT_MODEL
    if not path.exists():
        raise InputError(f"no model at {path}: train one with `formic train` or pass --model")
    return path


def make_policy(name: str, model: str | Path | None = None, greedy: bool = False) -> Policy | CentralPolicy:
    """A fresh policy object for ``name`` (the learned one loads ``model`` or the shipped one)."""
    cls = policy_class(name)
    if name == "formic":
        return cls.from_checkpoint(model_path(model), greedy=greedy)
    return cls(**_POLICIES[name][2])
