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

from .paired import SCENARIO_KEY, compare
from .paper import FIG5_SETTINGS, PAPER_SIZE, PAPER_STEPS, PAPER_TEAMS, paper_food
from .seed_stats import Estimate, OverSeeds, SeedComparison, compare_over_seeds, over_seeds

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


def seed_differences(per_seed: Mapping[str, Sequence[dict]], baseline: Sequence[dict]) -> dict[tuple, dict[str, float]]:
    """Per setting, each seed's paired mean difference with ``baseline`` (its food minus the
    baseline's, averaged over the scenarios both played there)."""
    out: dict[tuple, dict[str, float]] = {}
    for name, records in per_seed.items():
        for setting, difference in compare(records, baseline).items():
            out.setdefault(setting, {})[name] = difference.mean
    return out


def fig5_settings() -> list[tuple]:
    """Fig. 5's 24 cells as settings (size, agents, obstacles, env, steps), in the paper's order."""
    return [(PAPER_SIZE, n, obstacles, env, PAPER_STEPS) for env, obstacles in FIG5_SETTINGS for n in PAPER_TEAMS]


def published_food(setting: tuple) -> float | None:
    """The paper's ForMIC food in this setting (16 of Fig. 5's 24 cells are published)."""
    return paper_food({"algorithm": "formic", "variant": ""} | dict(zip(SETTING_KEY, setting)))


@dataclass(frozen=True)
class CellOverSeeds:
    """One Fig. 5 cell: each seed's mean food, the mean and IQM over seeds, the paper's food,
    and per baseline the comparison over seeds."""

    setting: tuple
    foods: dict[str, float]
    mean: Estimate
    iqm: Estimate
    paper: float | None
    versus: dict[str, SeedComparison]


@dataclass(frozen=True)
class SeedsStudy:
    """Every statistic over the seeds that the reports print."""

    names: list[str]
    cells: list[CellOverSeeds]
    paper_cells: list[tuple]  # the published cells every seed played, which ``paper_ratio`` pools
    paper_ratio: OverSeeds | None  # each seed's food / the paper's, over ``paper_cells``
    collapse_foods: dict[str, float]  # what the collapse rule reads, per seed
    collapse_source: str  # which food that is, in words

    def seed_paper_ratio(self) -> dict[str, float]:
        """Each seed's mean of food / the paper's over ``paper_cells``."""
        return {name: float(np.mean([cell.foods[name] / cell.paper for cell in self.cells
                                     if cell.setting in self.paper_cells])) for name in self.names}


def study(per_seed: Mapping[str, Sequence[dict]], baselines: Mapping[str, Sequence[dict]],
          validation_foods: Mapping[str, float] | None = None) -> SeedsStudy:
    """The statistics over seeds on Fig. 5's cells. ``per_seed``: each seed's test episodes (one
    algorithm, the paper's protocol); ``baselines``: per algorithm its episodes on the same
    scenarios. The collapse rule reads ``validation_foods`` (each seed's mean validation food);
    without them, each seed's mean test food over the cells every seed played, named as such."""
    names = list(per_seed)
    means = seed_means(per_seed)
    versus = {algorithm: seed_differences(per_seed, records) for algorithm, records in baselines.items()}
    cells = []
    for setting in fig5_settings():
        foods = means.get(setting, {})
        if not foods:
            continue
        summary = over_seeds(np.array(list(foods.values()))[:, None])
        cells.append(CellOverSeeds(
            setting, foods, summary.task_means[0], summary.task_iqms[0], published_food(setting),
            {algorithm: compare_over_seeds(list(by_setting[setting].values()))
             for algorithm, by_setting in versus.items() if by_setting.get(setting)}))
    everyone = [cell for cell in cells if len(cell.foods) == len(names)]
    published = [cell for cell in everyone if cell.paper]
    ratio = (over_seeds([[cell.foods[name] / cell.paper for cell in published] for name in names])
             if published else None)
    if validation_foods is not None:
        foods, source = dict(validation_foods), "mean validation food"
    else:
        foods = {name: float(np.mean([cell.foods[name] for cell in everyone])) if everyone else float("nan")
                 for name in names}
        source = f"mean test food over the {len(everyone)} Fig. 5 cells every seed played (no validation given)"
    return SeedsStudy(names, cells, [cell.setting for cell in published], ratio, foods, source)
