"""Where along a recipe run did its food come and go? Every stage's end on validation (issue 26).

A recipe run chooses its model among its last stages' means on validation scenarios; this plays
the end of every stage (``DIR/STAGE/mean.pt`` where the stage averages checkpoints, else
``DIR/STAGE/latest.pt``) on the same scenarios (the run's validation set, ``DIR/validation``,
never a test set) into ``DIR/validation/STAGE.mean`` or ``STAGE.latest``, the folders the
recipe's own candidates use, so their episodes are reused, and prints the mean food per team
size stage by stage. A stage not yet started is left out.

    .venv/bin/python scripts/stage_validation.py models/training/tables/reference --stages crowd,nonlearning
"""

from __future__ import annotations

import json
from pathlib import Path

import click

from formic_runtime.threads import configure_threads
from formic_trainer.recipes.definition import Validation
from formic_trainer.recipes.validation import play_validation, validation_matrix


def run_identity(run_dir: Path) -> dict:
    """What the run in ``run_dir`` trains and validates on, as its recipe stored it."""
    return json.loads(json.loads((run_dir / "recipe.json").read_text())["identity"])


def stage_ends(run_dir: Path, identity: dict) -> list[tuple[str, Path]]:
    """(name, weights) of the end of every started stage of the run, in order:
    ``STAGE.mean`` when the stage wrote its mean, else ``STAGE.latest``."""
    ends = []
    for stage in identity["stages"]:
        for part, file in (("mean", "mean.pt"), ("latest", "latest.pt")):
            weights = run_dir / stage["name"] / file
            if weights.is_file():
                ends.append((f"{stage['name']}.{part}", weights))
                break
    return ends


def run_validation(identity: dict) -> Validation:
    """The run's validation set."""
    v = identity["validation"]
    return Validation(v["seed"], v["size"], tuple(v["teams"]), v["scenarios"], v["steps"])


def table_lines(scores: dict[str, dict]) -> list[str]:
    """One line per stage end: mean food over all episodes, then per team size."""
    teams = sorted({int(n) for score in scores.values() for n in score["food_by_team"]})
    lines = [f"{'stage end':20s} {'episodes':>8s} {'food':>7s} " + " ".join(f"{n:>7d}" for n in teams)]
    for name, score in scores.items():
        by_team = {int(n): food for n, food in score["food_by_team"].items()}
        lines.append(f"{name:20s} {score['episodes']:8d} {score['food_mean']:7.1f} "
                     + " ".join(f"{by_team[n]:7.1f}" if n in by_team else f"{'-':>7s}" for n in teams))
    return lines


@click.command(help=__doc__.split("\n\n")[0])
@click.argument("run_dir", type=click.Path(exists=True, file_okay=False, path_type=Path))
@click.option("--stages", default="", help="Comma list of stage names to play (default: every started stage).")
def main(run_dir: Path, stages: str) -> None:
    configure_threads(1)
    wanted = {name for name in stages.split(",") if name}
    identity = run_identity(run_dir)
    ends = [(name, weights) for name, weights in stage_ends(run_dir, identity)
            if not wanted or name.split(".")[0] in wanted]
    if not ends:
        raise click.ClickException(f"{run_dir}: no started stage{' among ' + stages if wanted else ''}")
    folder = run_dir / "validation"
    matrix = validation_matrix(run_validation(identity), folder / "scenarios")
    scores = {}
    for name, weights in ends:
        click.echo(f"{name}: {weights} -> {folder / name}", err=True)
        scores[name] = play_validation(matrix, weights, folder / name)
    click.echo("\n".join(table_lines(scores)))


if __name__ == "__main__":
    main()
