#!/usr/bin/env python3
"""The recipe's seeds side by side: which one ships (validation) and how they all do (test).

    .venv/bin/python scripts/seeds_table.py \\
        --runs models/training/recipe-paper/seed1 models/training/recipe-paper/seed2 \\
        --evals eval/recipe-paper/seed1 eval/recipe-paper/seed2 --baselines eval/readme

``--runs``: each seed's ``formic train --recipe`` directory (its ``selection.json``). ``--evals``:
each seed's ``scripts/eval_model.sh`` folder, in the same order (a missing one leaves that
seed out of the test table). ``--baselines``: the baselines' episodes on the same scenarios
(``scripts/eval_readme.sh``). Prints markdown: the validation table and the seed chosen on
it, then per Fig. 5 cell each seed's food, the mean and the interquartile mean over seeds with
stratified bootstrap 95% intervals beside the paper's ForMIC, and against C-SAF-11 and
Cardinality-MR each seed's paired mean difference summarised over seeds (t and bootstrap 95%
intervals, and the verdict ahead/level/behind); then ForMIC / the paper over the published
cells, the collapse rate (on validation food) and the three targets of the eight-seed experiment, met or missed
(``formic_eval.seeds_report``). Without ``--runs``: every finished seed
(``models/training/recipe-paper/seedS`` with its ``selection.json``) and its
``eval/recipe-paper/seedS`` folder once sealed (an evaluation still being played is left out), the
results page's block (docs/results.md):

    .venv/bin/python scripts/seeds_table.py --write docs/results.md   # replace the block in place
    .venv/bin/python scripts/seeds_table.py --check docs/results.md   # exit 1 if the page is stale
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "src"))

from formic_eval.markdown_block import add_block_options, publish  # noqa: E402
from formic_eval.paper import RIVALS, test_set_episodes  # noqa: E402
from formic_eval.runner import LOG_NAME, EpisodeLog, folder_episodes  # noqa: E402
from formic_eval.seeds import SeedValidation, shipped_seed, spread, study  # noqa: E402
from formic_eval.seeds_report import seeds_report  # noqa: E402



def markers(recipe: str, planned: int | None) -> tuple[str, str]:
    """The block's begin and end markers: the first recipe's plain (the page's history), any other's
    naming the arguments that rebuild it, so that one page holds a block per recipe."""
    if recipe == "paper" and planned is None:
        return "<!-- seeds:begin (scripts/seeds_table.py) -->", "<!-- seeds:end -->"
    args = f"--recipe {recipe}" + (f" --planned {planned}" if planned else "")
    return f"<!-- seeds:begin (scripts/seeds_table.py {args}) -->", f"<!-- seeds:end {args} -->"


def sealed(folder: Path) -> bool:
    """An evaluation that has ended: its episodes sealed, no plain tail still being written
    (``scripts/train_seeds.sh`` seals a seed's test episodes once all are played)."""
    return EpisodeLog(folder / LOG_NAME).sealed


def episodes(folder: Path, algorithm: str) -> list[dict]:
    """The folder's plain (no variant) episodes of ``algorithm`` in the paper's test protocol."""
    return test_set_episodes(folder_episodes(folder), algorithm)


def validation_table(validations: list[SeedValidation]) -> list[str]:
    teams = sorted({n for v in validations for n in v.food_by_team})
    lines = ["| seed | chosen | " + " | ".join(f"{n} agents" for n in teams) + " | mean |",
             "|---|---|" + "---|" * (len(teams) + 1)]
    for v in validations:
        lines.append(f"| {v.name} | {v.chosen} | " + " | ".join(f"{v.food_by_team.get(n, float('nan')):.1f}"
                                                               for n in teams) + f" | {v.food_mean:.1f} |")
    ships = shipped_seed(validations)
    means, std = spread([v.food_mean for v in validations])
    lines += ["", f"Mean over seeds {means:.1f} ± {std:.1f}. Chosen to ship: **{ships.name}** ({ships.chosen}), "
              "the highest mean validation food (validation scenarios only; no test episode is read for the choice)."]
    return lines


def tables(runs: list[Path], evals: list[Path | None], baselines_folder: Path, planned: int | None = None) -> list[str]:
    """The validation table and the seed that ships, then the test table and the statistics over
    seeds; first, while fewer than ``planned`` seeds have finished, how far the experiment is."""
    validations = [SeedValidation.load(run) for run in runs]
    per_seed = {v.name: episodes(folder, "formic") if folder else [] for v, folder in zip(validations, evals)}
    per_seed = {name: records for name, records in per_seed.items() if records}
    baselines = {algorithm: episodes(baselines_folder, algorithm) for algorithm, _ in RIVALS}
    result = study(per_seed, baselines, {v.name: v.food_mean for v in validations})
    progress = [progress_line(len(runs), len(per_seed), planned), ""] if planned and len(runs) < planned else []
    return [*progress, "#### Validation", "", *validation_table(validations), "",
            "#### Test (Fig. 5's cells)", "", *seeds_report(result)]


def progress_line(finished: int, evaluated: int, planned: int) -> str:
    """How far an experiment of ``planned`` seeds is: its statistics so far are provisional."""
    return (f"**In progress: {finished} of the {planned} seeds fixed in advance have finished training, "
            f"{evaluated} of them with test episodes.** Everything below rests on those seeds alone; the "
            f"targets are judged on all {planned}.")


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--runs", nargs="+", type=Path, help="each seed's recipe run directory")
    parser.add_argument("--evals", nargs="*", type=Path, default=[],
                        help="each seed's eval_model.sh folder, same order")
    parser.add_argument("--baselines", type=Path, default=ROOT / "eval" / "readme", help="the baselines' eval folder")
    parser.add_argument("--recipe", default="paper",
                        help="without --runs: the recipe whose finished seeds to read (models/training/recipe-NAME, "
                             "eval/recipe-NAME)")
    parser.add_argument("--planned", type=int,
                        help="the number of seeds the experiment fixed in advance: while fewer have finished, the "
                             "block says so first")
    add_block_options(parser, "seeds")
    args = parser.parse_args()
    if args.runs is None:
        runs_folder = ROOT / "models" / "training" / f"recipe-{args.recipe}"
        if not runs_folder.is_dir():
            parser.error(f"--recipe {args.recipe}: no {runs_folder.relative_to(ROOT)}")
        args.runs = sorted((run for run in runs_folder.glob("seed*") if (run / "selection.json").is_file()),
                           key=lambda run: int(run.name[4:]) if run.name[4:].isdigit() else run.name)
        evals = ROOT / "eval" / f"recipe-{args.recipe}"  # a seed's test episodes count once all are played
        args.evals = [evals / run.name if sealed(evals / run.name) else None for run in args.runs]
    if args.evals and len(args.evals) != len(args.runs):
        parser.error(f"--evals names {len(args.evals)} folders for {len(args.runs)} runs")
    try:
        lines = (tables(args.runs, args.evals, args.baselines, args.planned) if args.runs else
                 [*([progress_line(0, 0, args.planned), ""] if args.planned else []), "(no finished seed yet)"])
    except ValueError as exc:
        sys.exit(f"seeds_table: {exc}")
    begin, end = markers(args.recipe, args.planned)
    return publish(lines, begin, end, args, "scripts/seeds_table.py")


if __name__ == "__main__":
    sys.exit(main())
