"""The paper's Tables I-III (ablations, non-learning agents, field of view) from evaluation folders.

Each row is the paper recipe trained with one switch (``formic train --recipe paper --switch
NAME``), evaluated on the stored test scenarios, in the episode log of ``ROOT/NAME``; the reference
(the unchanged recipe at the same budget) in ``ROOT/reference``; where the reference was trained
with several seeds (``eval/tables-seedS/reference``), their mean per scenario. As the paper
computed Table I, a row's relative performance is its food over the reference's on the same
scenarios, per cell of the test set "with/without obstacles, with/without wipeouts, all team sizes" (16 cells:
128x128, 1024 steps, infinite resources with and without 3 wipeouts, 0% and 5% obstacles, teams
16-128), then the mean and sample standard deviation over the cells. Beside that, per cell, the
paired difference of food on the same scenarios (``paired.compare``, a 95% interval) says whether
the row is behind the reference, level with it or ahead: the spread over cells mixes real
differences between cells with each cell's scenario noise, the paired intervals do not.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping, Sequence
import dataclasses
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .paired import compare, pair_records
from .paper import PAPER_SIZE, PAPER_STEPS, PAPER_TEAMS, test_set_episodes
from .runner import folder_episodes
from .seeds import mean_over_seeds

REFERENCE = "reference"
CELL_ENVS = ("infinite", "wipeout")
CELL_OBSTACLES = (0.0, 0.05)


@dataclass(frozen=True)
class TableRow:
    table: str  # "I", "II" or "III"
    label: str  # the paper's wording
    switch: str  # the recipe switch whose run it is (REFERENCE: the unchanged recipe)
    variant: str  # how it is tested: "" (as trained) or "no-pheromones" (the channel empty)
    paper: tuple[float, float]  # the paper's relative performance, mean and spread, in %


ROWS = (
    TableRow("I", "Training & testing without pheromones", "no-pheromones", "no-pheromones", (82.79, 10.00)),
    TableRow("I", "Training without pheromone curriculum", "no-curriculum", "", (75.89, 7.00)),
    TableRow("I", "Training without non-learning agents", "no-nonlearning", "", (72.58, 12.85)),
    TableRow("I", "Testing without pheromones (empty channel)", REFERENCE, "no-pheromones", (65.89, 8.73)),
    TableRow("I", "Training without invalid action pruning", "no-pruning", "", (6.29, 1.98)),
    TableRow("II", "32 learning + 0 non-learning agents", "learning-32-0", "", (105.33, 10.88)),
    TableRow("II", "16 learning + 16 non-learning agents", "learning-16-16", "", (94.16, 13.70)),
    TableRow("II", "8 learning + 24 non-learning agents", "learning-8-24", "", (102.11, 19.23)),
    TableRow("III", "FOV 5", "fov5", "", (59.61, 11.00)),
    TableRow("III", "FOV 21", "fov21", "", (105.79, 19.46)),
)


def cell_of(record: Mapping) -> tuple:
    """(env, obstacles, agents) of a test-set episode, or None outside the tables' 16 cells."""
    if (record["size"], record["steps"]) != (PAPER_SIZE, PAPER_STEPS) or record["env"] not in CELL_ENVS \
            or record["agents"] not in PAPER_TEAMS or not any(abs(record["obstacles"] - o) < 1e-9
                                                              for o in CELL_OBSTACLES):
        return None
    return record["env"], round(float(record["obstacles"]), 4), int(record["agents"])


def model_episodes(folder: Path, variant: str) -> list[dict]:
    """The learned model's episodes of one test variant in an evaluation folder, in the cells."""
    records = [r for r in test_set_episodes(folder_episodes(folder), "formic", variant) if cell_of(r) is not None]
    models = {r["model"] for r in records}
    if len(models) > 1:
        raise ValueError(f"{folder}: episodes of several models "
                         f"({', '.join(sorted(models))}); one row, one model")
    return records


def cell_ratios(row: Iterable[dict], reference: Iterable[dict]) -> dict[tuple, float]:
    """Per cell: the row's mean food over the reference's, on the scenarios both played."""
    ratios = {}
    for _, pairs in pair_records(row, reference).items():
        cell = cell_of(pairs[0][0])
        row_food = sum(a["food"] for a, _ in pairs)
        reference_food = sum(b["food"] for _, b in pairs)
        if reference_food > 0:
            ratios[cell] = row_food / reference_food
    return ratios


def cell_verdicts(row: Iterable[dict], reference: Iterable[dict]) -> tuple[int, int, int]:
    """How many cells the row is behind the reference in, level with and ahead of: by the 95%
    interval of the paired food difference on the scenarios both played."""
    behind = level = ahead = 0
    for difference in compare(row, reference).values():
        if difference.high < 0:
            behind += 1
        elif difference.low > 0:
            ahead += 1
        else:
            level += 1
    return behind, level, ahead


@dataclass(frozen=True)
class Relative:
    """A row's relative performance in %: mean and sample std over its cells, per team size, and
    (for a row against the reference) its cells behind / level / ahead by paired intervals."""

    mean: float
    std: float
    cells: int
    by_team: dict[int, float]
    verdicts: tuple[int, int, int] | None = None

    @classmethod
    def of(cls, ratios: Mapping[tuple, float]) -> Relative | None:
        if not ratios:
            return None
        values = 100.0 * np.array(list(ratios.values()))
        by_team = {n: float(100.0 * np.mean([r for (_, _, agents), r in ratios.items() if agents == n]))
                   for n in sorted({cell[2] for cell in ratios})}
        std = float(values.std(ddof=1)) if len(values) > 1 else 0.0
        return cls(float(values.mean()), std, len(values), by_team)


def reference_episodes(roots: Sequence[Path]) -> list[dict]:
    """The full model at the tables' budget, as trained: per scenario, the mean food over those
    of ``roots`` (folders like ``eval/tables``) whose reference has been evaluated; with one such
    root, its episodes. Several reference seeds make a steadier denominator for every row."""
    per_root = {str(root): model_episodes(root / REFERENCE, "") for root in roots}
    return mean_over_seeds({name: records for name, records in per_root.items() if records})


def relative_performance(reference: Sequence[dict], row: TableRow, seeds: Sequence[Path]) -> Relative | None:
    """The row's relative performance against ``reference`` (``reference_episodes``; None until the
    row is evaluated). ``seeds``: the folders (one per row each, like ``eval/tables``) whose
    evaluations of the row count; with several, the row's food per scenario is the mean over
    those seeds that evaluated it (``mean_over_seeds``), so the paired intervals are the mean's."""
    per_seed = {str(folder): model_episodes(folder / row.switch, row.variant) for folder in seeds}
    episodes = mean_over_seeds({name: records for name, records in per_seed.items() if records})
    found = Relative.of(cell_ratios(episodes, reference))
    return None if found is None else dataclasses.replace(found, verdicts=cell_verdicts(episodes, reference))


def evaluated_seeds(seed_roots: Sequence[Path], row: TableRow) -> list[Path]:
    """The folders of ``seed_roots`` where the row has been evaluated (its other seeds so far)."""
    return [folder for folder in seed_roots if model_episodes(folder / row.switch, row.variant)]


def seed_noise(seed_folders: Sequence[Path]) -> Relative | None:
    """The noise scale of one seed: each seed's food over the seeds' mean, per cell (the
    unchanged recipe, several seeds), pooled over seeds and cells."""
    per_seed = [model_episodes(folder, "") for folder in seed_folders]
    per_seed = [records for records in per_seed if records]
    if len(per_seed) < 2:
        return None
    pooled = mean_over_seeds({str(i): records for i, records in enumerate(per_seed)})
    ratios: dict[tuple, float] = {}
    for i, records in enumerate(per_seed):
        for cell, ratio in cell_ratios(records, pooled).items():
            ratios[(f"seed{i}", *cell)] = ratio
    values = 100.0 * np.array(list(ratios.values()))
    return Relative(float(values.mean()), float(values.std(ddof=1)), len(values), {})
