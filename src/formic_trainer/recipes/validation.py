"""The end of a run: the validation set (stored in the run directory, never a test set), every
candidate's episodes on it, and the choice by :data:`SELECTION_RULE` copied to ``model.pt``."""

from __future__ import annotations

import json
from pathlib import Path
from typing import TYPE_CHECKING

from formic_world.files import atomic_open

from .definition import RecipeError, Validation, stage_config, trained, weights_file
from .files import write_json

if TYPE_CHECKING:
    from .run import RecipeRun

SELECTION_RULE = ("the candidate with the highest mean food over all validation episodes (every team size "
                  "pooled, agents sampling); the first listed wins a tie")


def select_model(run: RecipeRun) -> Path:
    """Play every candidate on the validation scenarios, copy the best to ``model.pt`` and
    play it once more with the pheromone channel empty; ``selection.json`` has it all."""
    v, folder = run.recipe.validation, run.run_dir / "validation"
    matrix = validation_matrix(v, folder / "scenarios")
    # a model trained without pheromones is tested without them too (the paper's Table I row)
    blind = not trains_with_pheromones(run)
    scores = {name: _validate(run, matrix, weights_file(run.run_dir, name), folder / name, no_pheromones=blind)
              for name in run.recipe.candidates}
    chosen = max(run.recipe.candidates, key=lambda name: scores[name]["food_mean"])
    model = run.run_dir / "model.pt"
    with atomic_open(model, "wb") as handle:
        handle.write(weights_file(run.run_dir, chosen).read_bytes())
    empty = (scores[chosen] if blind else
             _validate(run, matrix, model, folder / f"{chosen}-channel-empty", no_pheromones=True))
    sampled = scores[chosen]["food_by_team"]
    less = {n: 1 - empty["food_by_team"][n] / sampled[n] if sampled[n] else 0.0 for n in sampled}
    write_json(run.run_dir / "selection.json", {
        "rule": SELECTION_RULE, "validation": trained(v) | {"scenarios_dir": str(folder / "scenarios")},
        "candidates": scores, "chosen": chosen, "model": str(model),
        "channel_empty": empty | {"less_by_team": less},
        "episodes": run.recipe.episodes, "cpu_hours": run.cpu_seconds / 3600})
    run.echo(f"model: {model} = {chosen} (validation food: "
             + ", ".join(f"{name} {s['food_mean']:.1f}" for name, s in scores.items()) + ")")
    run.echo(f"validation (seed {v.seed}: {v.size}x{v.size}, {v.steps} steps, {v.scenarios} per team size, "
             "sampling): agents / food / channel empty / less")
    for n in sampled:
        run.echo(f"  {n:4d}  {sampled[n]:8.1f}  {empty['food_by_team'][n]:8.1f}  {less[n]:5.0%}")
    run.echo(run.budget(len(run.recipe.stages)))
    return model


def finished_model(run: RecipeRun) -> Path | None:
    """``model.pt`` of a run whose choice is made, else None. A finished run keeps its model,
    selection, validation episodes and logs, not its stages' checkpoints: without this, running
    it again would train every stage from scratch."""
    if not (run.run_dir / "selection.json").exists():
        return None
    model, chosen = chosen_model(run.run_dir)
    run.echo(f"model: {model} = {chosen}, chosen on validation ({run.run_dir / 'selection.json'}): the run is finished")
    return model


def chosen_model(run_dir: Path) -> tuple[Path, str]:
    """``run_dir``'s ``model.pt`` and the candidate it is, checked against ``selection.json``
    (the file is the chosen candidate's copy); a RecipeError where the run has made no choice
    or the two disagree."""
    from formic_eval.matrix import file_digest

    selection_file, model = run_dir / "selection.json", run_dir / "model.pt"
    if not selection_file.exists():
        raise RecipeError(f"{run_dir} has made no choice yet (no selection.json): not a finished run")
    try:
        selection = json.loads(selection_file.read_text())
        chosen = selection["chosen"]
        digest = selection["candidates"][chosen]["digest"]
    except (ValueError, KeyError, TypeError) as exc:
        raise RecipeError(f"{selection_file} is not a readable choice ({exc.__class__.__name__}: {exc}): remove it "
                          "to validate and choose again") from None
    if not model.exists() or file_digest(model) != digest:
        raise RecipeError(f"{model} is not the {chosen} that {selection_file} chose: restore it, or remove "
                          "selection.json to validate and choose again")
    return model, chosen


def trains_with_pheromones(run: RecipeRun) -> bool:
    """Whether the recipe's agents see the pheromone channel (every stage does the same)."""
    stages = range(len(run.recipe.stages))
    seen = {stage_config(run.recipe, i, run.run_dir, run.seed).pheromones for i in stages}
    if len(seen) > 1:
        raise RecipeError("stages differ in `pheromones`: the validation cannot test them alike")
    return seen.pop()


def _validate(run: RecipeRun, matrix: dict, model: Path, out: Path, no_pheromones: bool = False) -> dict:
    """``model`` on the validation scenarios; their one-thread episode clock joins the run's CPU budget."""
    run.echo(f"validation: {model}{' (pheromone channel empty)' if no_pheromones else ''} -> {out}")
    score = play_validation(matrix, model, out, no_pheromones, workers=run.threads or 1)
    run.cpu_seconds += score["cpu_seconds"]
    return {key: value for key, value in score.items() if key != "cpu_seconds"}


def validation_matrix(validation: Validation, folder: Path) -> dict:
    """The validation scenarios, written into (or kept in) ``folder``: 128x128-style worlds of
    ``validation``'s size, infinite resources, no obstacles, one setting per team size."""
    from formic_eval import generate_matrix, settings_grid

    v = validation
    grid = settings_grid([v.size], v.teams, [0.0], ["infinite"], v.steps)
    return generate_matrix(grid, v.scenarios, v.seed, folder)


def play_validation(matrix: dict, model: Path, out: Path, no_pheromones: bool = False, workers: int = 1) -> dict:
    """``model`` on ``matrix`` (episodes kept in ``out``, reused when there) in ``workers``
    one-thread processes: its file, digest, episodes, mean food over them all and per team size,
    and the episodes' CPU seconds."""
    from formic_eval import PolicyOptions, evaluate
    from formic_eval.matrix import file_digest
    from formic_eval.runner import folder_episodes

    options = PolicyOptions(model=str(model), model_digest=file_digest(model), no_pheromones=no_pheromones)
    summary = evaluate(matrix, ["formic"], options, out, workers=workers, source=str(out.parent / "scenarios"))
    if summary["interrupted"]:
        raise KeyboardInterrupt
    cells = summary["cells"]
    n = sum(c["n"] for c in cells)
    return {"file": str(model), "digest": options.model_digest, "episodes": n,
            "food_mean": sum(c["n"] * c["food_mean"] for c in cells) / n,
            "food_by_team": {c["agents"]: c["food_mean"] for c in cells},
            "cpu_seconds": sum(record["wall_s"] for record in folder_episodes(out))}
