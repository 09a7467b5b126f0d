"""What a recipe is: its stages, its validation set and the identity a run is held to, and the
weights and training configuration each stage names."""

from __future__ import annotations

import json
from dataclasses import asdict, dataclass
from pathlib import Path

from formic_world.errors import InputError

from ..config import TrainConfig, make_config

# a stage reference's part -> the file in the stage's folder: "NAME", "NAME.mean", "NAME.best"
WEIGHTS = {"": "latest.pt", "mean": "mean.pt", "best": "best.pt"}


class RecipeError(InputError):
    """A recipe (or a run directory) that cannot be used, with the reason in one line."""


@dataclass(frozen=True)
class Stage:
    name: str
    episodes: int
    start: str  # "scratch", an earlier stage's name (its final weights), "<stage>.mean" or "<stage>.best"
    settings: dict  # every TrainConfig field this stage sets, inherited ones included
    average: tuple[int, int] | None  # (first, every): the mean of the checkpoints first, first+every, ..., episodes
    cost: float | None = None  # planned CPU-seconds per episode (the progress line's time left; not identity)

    def snapshots(self) -> tuple[int, ...]:
        """The episodes whose weights the stage's mean averages."""
        return () if self.average is None else tuple(range(self.average[0], self.episodes + 1, self.average[1]))


@dataclass(frozen=True)
class Validation:
    """The validation set: ``scenarios`` per team size, generated like ``formic eval --seed``."""

    seed: int
    size: int
    teams: tuple[int, ...]
    scenarios: int
    steps: int
    cost: float | None = None  # planned CPU-seconds per validation episode (not identity)

    @property
    def episodes(self) -> int:
        """Episodes one model plays on the validation set."""
        return self.scenarios * len(self.teams)


@dataclass(frozen=True)
class Recipe:
    source: Path
    text: str
    preset: str
    budget_cpu_hours: float
    stages: tuple[Stage, ...]
    candidates: tuple[str, ...]
    validation: Validation
    switch: str = ""  # the switch applied to every stage ("" = the recipe as written)
    switches: tuple[str, ...] = ()  # every switch the file defines
    scale: float = 1.0  # every scaled stage's episodes, means and schedules times this (an equal, smaller budget)

    @property
    def episodes(self) -> int:
        return sum(stage.episodes for stage in self.stages)

    @property
    def identity(self) -> str:
        """What a run of this recipe trains and how it chooses, as canonical JSON: a run
        directory resumes only under the same identity (comments, the budget line and other
        switches and the planned costs may change in between)."""
        return json.dumps({"preset": self.preset, "stages": [trained(stage) for stage in self.stages],
                           "candidates": self.candidates, "validation": trained(self.validation)},
                          sort_keys=True)


def trained(part: Stage | Validation) -> dict:
    """A stage or the validation as a run's identity holds it: without its planned cost."""
    return {key: value for key, value in asdict(part).items() if key != "cost"}


def weights_file(run_dir: Path, ref: str) -> Path:
    """The file a stage reference names: ``DIR/<stage>/latest.pt``, ``mean.pt`` or ``best.pt``."""
    name, _, part = ref.partition(".")
    return run_dir / name / WEIGHTS[part]


def stage_config(recipe: Recipe, index: int, run_dir: Path, seed: int, threads: int | None = None) -> TrainConfig:
    """Stage ``index``'s training configuration; its seed is 1000 * seed + index + 1, so no two
    stages of a run and no two runs of seeds below 1000 share a random stream. ``threads``
    replaces the stage's torch threads (speed only: a stage may resume with another count)."""
    stage = recipe.stages[index]
    start = None if stage.start == "scratch" else str(weights_file(run_dir, stage.start))
    settings = stage.settings if threads is None else {**stage.settings, "threads": threads}
    return make_config(recipe.preset, **settings, seed=1000 * seed + index + 1,
                       total_episodes=stage.episodes, init_weights=start)
