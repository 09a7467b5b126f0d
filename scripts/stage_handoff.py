"""How each paper-recipe run went from its basics stage into its reference stage, from the runs'
TensorBoard logs (a markdown table, runs sorted by the basics stage's last valid-action share):

    .venv/bin/python scripts/stage_handoff.py models/training/tables/* models/training/tables-seed2/*

Per run: the basics stage's last logged episode set (the share of free agents' actions that were
valid, and the food per world), then the reference stage's food per world: its first episode
set, the lowest over its first 40 episodes, and the mean after episode 40 (a run that fell to
random level, ~5-20 a world, stays there). The basics stage anneals the action filter away; the
reference stage brings back a strict filter for loaded agents and changes the rewards at once.
Folders without both stages (a run still in its basics stage) are listed as skipped; files are ignored.
"""

from __future__ import annotations

from pathlib import Path

import click
import numpy as np

from formic_trainer.scalars import read_scalars

EARLY = 40  # the reference stage's episodes in which a fall shows


def handoff(run_dir: Path) -> dict[str, float | None]:
    """The numbers of one run (a ``formic train --recipe paper`` folder)."""
    basics, reference = read_scalars(run_dir / "basics"), read_scalars(run_dir / "reference")
    food = reference["train/food_mean"]
    late = [value for episode, value in food if episode > EARLY]
    return {"valid_share": basics["train/valid_rate"][-1][1], "basics_food": basics["train/food_mean"][-1][1],
            "first_food": food[0][1], "lowest_early": min(value for episode, value in food if episode <= EARLY),
            "mean_late": float(np.mean(late)) if late else None, "episodes": food[-1][0]}


def has_stages(run_dir: Path) -> bool:
    return all(any((run_dir / stage / "tb").glob("events.out.tfevents.*")) for stage in ("basics", "reference"))


@click.command(help=__doc__.split("\n\n")[0])
@click.argument("runs", nargs=-1, required=True, type=click.Path(path_type=Path))
def main(runs: tuple[Path, ...]) -> None:
    found = {run: handoff(run) for run in runs if has_stages(run)}
    click.echo(f"| run | basics: valid share | basics: food | reference: first | lowest, episodes 1-{EARLY} "
               f"| mean after {EARLY} | reference episodes logged |")
    click.echo("|---|---|---|---|---|---|---|")
    for run, numbers in sorted(found.items(), key=lambda item: item[1]["valid_share"]):
        late = "–" if numbers["mean_late"] is None else f"{numbers['mean_late']:.1f}"  # not there yet
        click.echo(f"| {run} | {numbers['valid_share']:.2f} | {numbers['basics_food']:.1f} "
                   f"| {numbers['first_food']:.1f} | {numbers['lowest_early']:.1f} | {late} "
                   f"| {numbers['episodes']} |")
    skipped = [str(run) for run in runs if run.is_dir() and run not in found]  # a glob's log files: not runs
    if skipped:
        click.echo(f"\nskipped (no basics and reference stages logged): {', '.join(skipped)}")


if __name__ == "__main__":
    main()
