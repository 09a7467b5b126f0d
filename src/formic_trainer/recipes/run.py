"""Running a recipe: each stage trained (or skipped, or resumed) in its folder, the snapshots
its checkpoint mean needs, the mean, each finished stage's ``progress.json`` (its counters, which
the model card reads once the checkpoints are gone) and its ``latest.pt`` without the optimiser's
state (a third of the size: no later stage resumes it), and the progress line's budget and time
left; the validation and the choice that end a run are :mod:`.validation`'s."""

from __future__ import annotations

import json
from collections.abc import Callable
from pathlib import Path

from formic_agent.checkpoint import read_checkpoint
from formic_world.files import held_directory

from ..averaging import averaged_from, write_average
from ..config import make_config
from ..learner import drop_optimizer_state
from ..train import Trainer, export_model
from .definition import Recipe, RecipeError, Stage, stage_config
from .files import held_identity, shown_recipe, write_json
from .validation import chosen_model, finished_model, select_model

# a stage's own CPU clock per episode replaces its planned `cost` once it has run this many episodes
MEASURED_AFTER = 8


def cpu_seconds_left(recipe: Recipe, index: int, episode: int = 0, cpu_seconds: float = 0.0,
                     validated: bool = False, with_pheromones: bool = True) -> float | None:
    """The CPU-seconds a run still needs with stage ``index`` in progress at ``episode``, having
    spent ``cpu_seconds`` on it (the stages before it done, those after it not started; ``index``
    = the number of stages: all done): each unfinished stage's episodes left at its measured cost
    per episode once it has run :data:`MEASURED_AFTER` episodes, else at its planned ``cost``; and
    the validation's planned cost (every candidate, and the chosen one again with the pheromone
    channel empty when the recipe trains ``with_pheromones``) unless ``validated``. A stage that
    ends on its schedule clock (``schedule_end``) is counted to that episode (the clock may hold
    back a few episodes more). None where a cost is needed and the recipe plans none."""
    left = 0.0
    for i, stage in enumerate(recipe.stages[index:], start=index):
        done = episode if i == index else 0
        cost = cpu_seconds / done if done >= MEASURED_AFTER else stage.cost
        end = min(stage.episodes, stage.settings.get("schedule_end") or stage.episodes)  # 0 spells off
        if done < end:
            if cost is None:
                return None
            left += (end - done) * cost
    if not validated:
        v = recipe.validation
        if v.cost is None:
            return None
        left += v.cost * v.episodes * (len(recipe.candidates) + with_pheromones)
    return left


def _progress(checkpoint: Path) -> dict:
    """The counters of a stage's ``latest.pt`` (zero before it exists): episodes, CPU-seconds and
    the schedule clock's episode."""
    if not checkpoint.exists():
        return {"episode": 0, "cpu_seconds": 0.0, "schedule": 0}
    return _counters(read_checkpoint(checkpoint)["progress"])


def _counters(progress: dict) -> dict:
    return {"episode": progress["episode"], "cpu_seconds": progress.get("cpu_seconds", progress["seconds"]),
            "schedule": progress.get("schedule", {"episode": progress["episode"]})["episode"]}


def _ended(stage: Stage, progress: dict) -> bool:
    """Whether a stage at ``progress`` is over: its episodes played, or its clock at ``schedule_end``."""
    end = stage.settings.get("schedule_end") or None  # 0 spells off in a recipe
    return progress["episode"] >= stage.episodes or (end is not None and progress["schedule"] >= end)


def run_status(recipe: Recipe, run_dir: Path, seed: int) -> list[str]:
    """Where a run stands, read from its files alone and without its lock (it may be training):
    each stage complete, in progress or not started, with its episodes and CPU-hours (a finished
    stage's counters from its ``progress.json`` once its checkpoint is gone); the validation
    episodes played; the choice once made; the CPU-hours spent and left (as the progress line
    counts them, the validation's left at its planned cost per episode)."""
    from formic_eval.runner import folder_episodes

    claim = run_dir / "recipe.json"
    if not claim.exists():
        return [f"{run_dir}: not started"]
    held = json.loads(claim.read_text())
    if (held["seed"], held_identity(held)) != (seed, recipe.identity):
        raise RecipeError(f"{run_dir} holds a run of another recipe, switch, scale or seed ({claim})")
    lines, spent, current = [], 0.0, None
    for index, stage in enumerate(recipe.stages):
        where = run_dir / stage.name
        stored = where / "progress.json"
        progress = (_counters(json.loads(stored.read_text())) if stored.exists() and not (where / "latest.pt").exists()
                    else _progress(where / "latest.pt"))
        spent += progress["cpu_seconds"]
        done = f"{progress['episode']} of {stage.episodes} episodes, {progress['cpu_seconds'] / 3600:.2f} CPU-h"
        end = stage.settings.get("schedule_end") or None
        if _ended(stage, progress):
            lines.append(f"{stage.name}: complete, {done}")
            continue
        current = current or (index, progress)
        if progress["episode"]:
            clock = "" if end is None else f" (its clock at {progress['schedule']}, ending it at {end})"
            lines.append(f"{stage.name}: in progress, {done}{clock}")
        else:
            lines.append(f"{stage.name}: not started ({stage.episodes} episodes)")
    v, folder = recipe.validation, run_dir / "validation"
    kept = sorted(d for d in folder.iterdir() if d.is_dir() and d.name != "scenarios") if folder.is_dir() else []
    records = {d.name: folder_episodes(d) for d in kept}
    played = {name: len(episodes) for name, episodes in records.items()}
    spent += sum(r["wall_s"] for episodes in records.values() for r in episodes)
    lines.append("validation: " + (", ".join(f"{name} {n} of {v.episodes} episodes" for name, n in played.items())
                                   or "not started"))
    hours = f"{spent / 3600:.2f} of {recipe.budget_cpu_hours:.1f} CPU-h spent"
    if (run_dir / "selection.json").exists():
        _, chosen = chosen_model(run_dir)  # a RecipeError where the model is not the one chosen
        food = json.loads((run_dir / "selection.json").read_text())["candidates"][chosen]["food_mean"]
        return [*lines, f"finished: model.pt = {chosen} (validation food {food:.1f}); {hours}"]
    with_pheromones = make_config(recipe.preset, **recipe.stages[-1].settings).pheromones
    index, progress = current or (len(recipe.stages), {"episode": 0, "cpu_seconds": 0.0})
    left = cpu_seconds_left(recipe, index, progress["episode"], progress["cpu_seconds"], True, with_pheromones)
    if left is not None and v.cost is not None:  # the validation's episodes not yet played
        left += v.cost * max(0, v.episodes * (len(recipe.candidates) + with_pheromones) - sum(played.values()))
    return [*lines, hours + ("" if left is None or v.cost is None else f", ~{left / 3600:.1f} CPU-h left")]


def run_recipe(recipe: Recipe, run_dir: Path, seed: int, echo: Callable[[str], None] = print,
               threads: int | None = None) -> Path:
    """Run (or resume) every stage of ``recipe`` in ``run_dir``, then choose the model on
    validation; returns ``run_dir/model.pt``. The run holds ``run_dir`` throughout: a second
    process on the same folder fails at once. ``threads``: torch threads for every stage and
    processes for validation, instead of the recipe's (how fast, not what is trained: not part of
    the run's identity, so a run may resume with another count)."""
    if threads is not None and threads < 1:
        raise ValueError(f"threads must be at least 1, not {threads}")
    with held_directory(run_dir):
        run = RecipeRun(recipe, Path(run_dir), seed, echo, threads)
        if (model := finished_model(run)) is not None:
            return model
        for index in range(len(recipe.stages)):
            run.stage(index)
        return select_model(run)


class RecipeRun:
    """One run of a recipe: its directory, and the budget it has spent (for the progress lines)."""

    def __init__(self, recipe: Recipe, run_dir: Path, seed: int, echo: Callable[[str], None],
                 threads: int | None = None):
        self.recipe, self.run_dir, self.seed, self.echo, self.threads = recipe, run_dir, seed, echo, threads
        self.trainer: Trainer | None = None  # the trainer of the stage in progress
        self.episodes, self.cpu_seconds = 0, 0.0  # of the stages finished
        claim = run_dir / "recipe.json"  # a folder holds one run: a skipped or resumed stage is this recipe's
        held = json.loads(claim.read_text()) if claim.exists() else None
        if held is None:
            write_json(claim, {"recipe": shown_recipe(recipe.source), "seed": seed, "switch": recipe.switch,
                               "scale": recipe.scale, "identity": recipe.identity, "text": recipe.text})
        elif (held["seed"], held_identity(held)) != (seed, recipe.identity):
            raise RecipeError(f"{run_dir} holds a run of another recipe, switch, scale or seed ({claim}): "
                              "use a new --run-dir")

    def budget(self, index: int, episode: int = 0, cpu_seconds: float = 0.0) -> str:
        """The progress line's budget with stage ``index`` at ``episode`` after ``cpu_seconds``
        (``index`` = the number of stages: the run is over, validation included): episodes
        done, CPU-hours spent and, where the costs are known, the CPU-hours left."""
        recipe = self.recipe
        hours, budget = (self.cpu_seconds + cpu_seconds) / 3600, recipe.budget_cpu_hours
        with_pheromones = make_config(recipe.preset, **recipe.stages[-1].settings).pheromones
        left = cpu_seconds_left(recipe, index, episode, cpu_seconds, index == len(recipe.stages), with_pheromones)
        return (f"recipe {self.episodes + episode}/{recipe.episodes} episodes, {hours:.2f}/{budget:.1f} CPU-h"
                f"{' (over budget)' if hours > budget else ''}"
                f"{'' if left is None else f', ~{left / 3600:.1f} CPU-h left'}")

    def stage(self, index: int) -> None:
        """Train stage ``index`` to its end in chunks that stop at every episode its mean
        needs (a snapshot of the weights is taken there), then write the mean."""
        stage, count = self.recipe.stages[index], len(self.recipe.stages)
        where = self.run_dir / stage.name
        progress = _progress(where / "latest.pt")
        episode, ended = progress["episode"], _ended(stage, progress)
        if ended:
            self.echo(f"stage {index + 1}/{count} {stage.name}: complete ({episode} episodes), skipped")
        else:
            fresh = "" if stage.start == "scratch" else " (a fresh optimiser)"
            resume = f", resuming at episode {episode}" if episode else ""
            resume += f", {self.threads} torch thread(s)" if self.threads else ""
            self.echo(f"stage {index + 1}/{count} {stage.name}: {stage.episodes} episodes from {stage.start}{fresh}"
                      f"{resume} | {self.budget(index, episode, progress['cpu_seconds'])}")
            cfg = stage_config(self.recipe, index, self.run_dir, self.seed, self.threads)
            while not ended:
                self.snapshot(stage, episode)
                self.trainer = None  # while it starts: its lines carry no budget yet
                self.trainer = Trainer(cfg, where, log=lambda line: self.log(index, line))
                stop = min([e for e in stage.snapshots() if e > episode] + [stage.episodes])
                self.trainer.train(episodes=stop - episode)
                episode, ended = self.trainer.episode, self.trainer.ended
            self.trainer = None
        self.snapshot(stage, episode)
        # the stage's counters where they outlive its checkpoint (a finished run keeps no latest.pt)
        write_json(where / "progress.json", read_checkpoint(where / "latest.pt")["progress"])
        drop_optimizer_state(where / "latest.pt")  # the next stage starts a fresh optimiser
        if stage.average is not None:
            self.average(stage)
        wanted = {s.start for s in self.recipe.stages} | set(self.recipe.candidates)
        if f"{stage.name}.best" in wanted and not (where / "best.pt").exists():
            raise RecipeError(f"{where}: no best.pt, which {stage.name}.best names: its fall guard never saw "
                              "guard_window episode sets after guard_after")
        self.episodes += episode
        self.cpu_seconds += _progress(where / "latest.pt")["cpu_seconds"]

    def log(self, index: int, line: str) -> None:
        trainer = self.trainer
        budget = "" if trainer is None else " | " + self.budget(index, trainer.episode, trainer.learner.cpu_seconds)
        self.echo(f"{self.recipe.stages[index].name}: {line}{budget}")

    def snapshot_file(self, stage: Stage, episode: int) -> Path:
        return self.run_dir / stage.name / "snapshots" / f"episode{episode:05d}.pt"

    def snapshot(self, stage: Stage, episode: int) -> None:
        """Keep the weights of ``episode`` when the stage's mean needs them (once; never once the
        mean is written, which happens after its last snapshot)."""
        target, mean = self.snapshot_file(stage, episode), self.run_dir / stage.name / "mean.pt"
        if episode in stage.snapshots() and not target.exists() and not mean.exists():
            export_model(self.run_dir / stage.name / "latest.pt", target)

    def average(self, stage: Stage) -> None:
        """Write the stage's mean unless ``mean.pt`` already is the mean of its snapshots
        (:func:`~formic_trainer.averaging.averaged_from`: a finished stage's mean stands for
        those no longer kept, so a run in progress need not track them)."""
        where = self.run_dir / stage.name
        inputs = [self.snapshot_file(stage, e) for e in stage.snapshots()]
        mean = where / "mean.pt"
        if averaged_from(mean, inputs):
            return
        missing = [p.name for p in inputs if not p.exists()]
        if missing:
            raise RecipeError(f"{where}: the mean needs {', '.join(missing)}, which this run did not keep")
        write_average(inputs, mean)
        self.echo(f"{stage.name}: mean.pt = the mean of episodes {', '.join(map(str, stage.snapshots()))}")
