"""Several training seeds of one recipe, side by side (issue 25: seeds and their spread).

Each seed's run directory holds its validation choice (``selection.json``, written by
``formic train --recipe``); its test episodes come from ``scripts/eval_model.sh`` on the stored
test scenarios. Which seed ships is decided on validation only, by the recipe's own rule; the test
set reports every seed, their mean and spread, and the mean over seeds against the baselines
on the same scenarios (per scenario, the seeds' mean food minus the baseline's).
"""

from __future__ import annotations

import json
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .paired import SCENARIO_KEY

SETTING_KEY = SCENARIO_KEY[:-1]  # size, agents, obstacles, env, steps


@dataclass(frozen=True)
class SeedValidation:
    """One seed's validation result (its ``selection.json``)."""

    name: str
    chosen: str
    food_mean: float
    food_by_team: dict[int, float]

    @classmethod
    def load(cls, run_dir: str | Path) -> SeedValidation:
        path = Path(run_dir) / "selection.json"
        try:
            data = json.loads(path.read_text())
            score = data["candidates"][data["chosen"]]
            by_team = {int(n): float(food) for n, food in score["food_by_team"].items()}
            return cls(Path(run_dir).name, data["chosen"], float(score["food_mean"]), by_team)
        except (OSError, ValueError, KeyError, TypeError) as exc:
            raise ValueError(f"{path}: no readable validation choice ({exc})") from exc


def shipped_seed(validations: Sequence[SeedValidation]) -> SeedValidation:
    """The seed to ship: the highest mean validation food (the recipe's selection rule applied
    across seeds); the first listed wins a tie."""
    if not validations:
        raise ValueError("no seeds to choose from")
    return max(validations, key=lambda v: v.food_mean)  # max keeps the first of equals


def setting_of(record: Mapping) -> tuple:
    return tuple(record[k] for k in SETTING_KEY)


def seed_means(per_seed: Mapping[str, Sequence[dict]]) -> dict[tuple, dict[str, float]]:
    """Per setting, each seed's mean food over its episodes there."""
    out: dict[tuple, dict[str, list[float]]] = {}
    for name, records in per_seed.items():
        for record in records:
            out.setdefault(setting_of(record), {}).setdefault(name, []).append(float(record["food"]))
    return {setting: {name: float(np.mean(foods)) for name, foods in by_seed.items()}
            for setting, by_seed in out.items()}


def spread(values: Sequence[float]) -> tuple[float, float]:
    """Mean and sample standard deviation (0 for one value) over seeds."""
    array = np.asarray(values, dtype=np.float64)
    return float(array.mean()), float(array.std(ddof=1)) if len(array) > 1 else 0.0


def mean_over_seeds(per_seed: Mapping[str, Sequence[dict]]) -> list[dict]:
    """One record per scenario that every seed played: the first seed's record with ``food``
    the seeds' mean there, ``seeds`` how many. Scenarios some seed lacks are left out, so a
    comparison never mixes seeds across scenarios."""
    if not per_seed:
        return []
    indexed = []
    for name, records in per_seed.items():
        found: dict[tuple, dict] = {}
        for record in records:
            key = tuple(record[k] for k in SCENARIO_KEY)
            if key in found:
                raise ValueError(f"{name}: two episodes on one scenario {key}")
            found[key] = record
        indexed.append(found)
    common = set(indexed[0]).intersection(*indexed[1:])
    return [indexed[0][key] | {"food": float(np.mean([seed[key]["food"] for seed in indexed])),
                               "seeds": len(indexed)}
            for key in sorted(common, key=str)]
