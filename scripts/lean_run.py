#!/usr/bin/env python3
"""Trim a finished recipe run to what the repository keeps of it.

    .venv/bin/python scripts/lean_run.py models/training/recipe-paper-v6/seed3

A finished run (its ``selection.json`` written and ``model.pt`` the chosen candidate's copy;
``formic train --recipe`` on it says it is finished) keeps its model, its selection, its
validation episodes (sealed: ``episodes.jsonl.gz`` with ``results.md`` and ``results.csv``),
each stage's ``config.json`` and ``progress.json``, ``recipe.json`` and its log. This removes the
rest: every stage's checkpoints, snapshots and TensorBoard files, the validation's regenerated
scenarios, the derived exports and figures (lock files stay: git ignores them, and removing one
another process may hold would let a third in). It refuses a run that is not finished, or that a
process holds (one still validating), and prints what each part weighed before and after.
"""

from __future__ import annotations

import argparse
import shutil
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "scripts"))
sys.path.insert(0, str(ROOT / "src"))

from seal_episodes import seal  # noqa: E402

from formic_trainer.recipes.validation import chosen_model  # noqa: E402
from formic_world.errors import InputError  # noqa: E402
from formic_world.files import held_directory  # noqa: E402


def size(path: Path) -> int:
    return sum(p.stat().st_size for p in path.rglob("*") if p.is_file()) if path.is_dir() else path.stat().st_size


def lean(run: Path) -> list[str]:
    """Trim ``run``; the lines to print."""
    chosen_model(run)  # RecipeError unless finished
    before = size(run)
    lines = []
    with held_directory(run):  # InputError while the run's own process holds it
        validation = run / "validation"
        kept = sorted(d for d in validation.iterdir() if d.is_dir() and d.name != "scenarios")
        lines += [seal(folder, drop_derived=True) for folder in kept]
        shutil.rmtree(validation / "scenarios", ignore_errors=True)
        for stage in sorted(p for p in run.iterdir() if p.is_dir() and p.name != "validation"):
            for name in ("snapshots", "tb"):
                shutil.rmtree(stage / name, ignore_errors=True)
            for checkpoint in stage.glob("*.pt"):
                checkpoint.unlink()
    lines.append(f"{run}: {before:,} -> {size(run):,} bytes")
    return lines


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("runs", nargs="+", type=Path, metavar="RUN_DIR", help="a finished `formic train --recipe` run")
    args = parser.parse_args(argv)
    for run in args.runs:
        try:
            print("\n".join(lean(run)))
        except (InputError, ValueError) as exc:
            print(f"lean_run: {exc}", file=sys.stderr)
            return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
