#!/usr/bin/env python3
"""Evaluate every finished row of the paper's Tables I-III the way scripts/paper_tables.py reads them.

    .venv/bin/python scripts/eval_tables.py models/training/tables eval/tables [--workers N]

RUNS holds one ``formic train --recipe paper --switch NAME`` run per row (``RUNS/NAME/model.pt``)
and the reference row (``RUNS/reference``). Each finished run plays the tables' 16 cells (128x128,
1024 steps, infinite resources with and without 3 wipeouts, 0% and 5% obstacles, 16-128 agents)
on the README's stored scenarios (``formic eval --seed 7``, 20 per cell) into ``OUT/NAME``, tested
as its rows say (``formic_eval.tables.ROWS``: as trained, or with the pheromone channel empty).
A run without its model yet is listed and skipped; finished episodes are reused, so it resumes.
``FORMIC`` may name another way to call the CLI. Then rebuild the tables with ``scripts/paper_tables.py OUT``.
"""

from __future__ import annotations

import argparse
import os
import shlex
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "src"))

from formic_eval.paper import PAPER_SIZE, PAPER_STEPS, PAPER_TEAMS  # noqa: E402
from formic_eval.tables import CELL_ENVS, CELL_OBSTACLES, REFERENCE, ROWS  # noqa: E402

TEST_SEED, SCENARIOS = 7, 20  # the README's stored test scenarios (scripts/eval_readme.sh)


def plan() -> list[tuple[str, str]]:
    """(switch, variant) of every evaluation the tables read, each once: the reference as
    trained first (every row is relative to it), then the rows in ROWS order."""
    wanted = [(REFERENCE, "")]
    for row in ROWS:
        if (row.switch, row.variant) not in wanted:
            wanted.append((row.switch, row.variant))
    return wanted


def command(formic: list[str], model: Path, out: Path, variant: str, workers: int) -> list[str]:
    cells = ["--sizes", str(PAPER_SIZE), "--teams", ",".join(map(str, PAPER_TEAMS)),
             "--obstacles", ",".join(f"{o:g}" for o in CELL_OBSTACLES), "--env", ",".join(CELL_ENVS)]
    tested = ["--no-pheromones"] if variant == "no-pheromones" else []
    return [*formic, "eval", "--algorithms", "formic", "--model", str(model), "--seed", str(TEST_SEED),
            "--steps", str(PAPER_STEPS), *cells, "--scenarios", str(SCENARIOS), *tested,
            "--workers", str(workers), "--out", str(out)]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("runs", type=Path, help="the folder of the rows' training runs")
    parser.add_argument("out", type=Path, help="the folder of the rows' evaluation folders")
    parser.add_argument("--workers", type=int, default=2, help="formic eval's worker processes")
    parser.add_argument("--dry-run", action="store_true", help="print each formic eval command instead")
    args = parser.parse_args()
    formic = shlex.split(os.environ.get("FORMIC", str(ROOT / ".venv" / "bin" / "formic")))
    for switch, variant in plan():
        model = args.runs / switch / "model.pt"
        tested = "the channel empty" if variant else "as trained"
        if not model.is_file():
            print(f"{switch} ({tested}): no {model} yet, skipped", flush=True)
            continue
        evaluation = command(formic, model, args.out / switch, variant, args.workers)
        print(f"{switch} ({tested}): {shlex.join(evaluation) if args.dry_run else model}", flush=True)
        if args.dry_run:
            continue
        done = subprocess.run(evaluation)
        if done.returncode:
            sys.exit(f"eval_tables: formic eval of {model} failed (exit {done.returncode})")


if __name__ == "__main__":
    main()
