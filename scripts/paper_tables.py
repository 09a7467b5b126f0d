#!/usr/bin/env python3
"""The paper's Tables I-III rebuilt from evaluation folders, beside the paper's (markdown).

    .venv/bin/python scripts/paper_tables.py eval/tables [--seeds eval/recipe-paper/seed1 eval/recipe-paper/seed2]
        [--row-seeds eval/tables-seed2]
    .venv/bin/python scripts/paper_tables.py --write docs/results.md   # the results page's block, from the defaults
    .venv/bin/python scripts/paper_tables.py --check docs/results.md   # exit 1 if the page is stale

ROOT holds one folder per row, named by its recipe switch (``ROOT/no-curriculum``, ...), and
``ROOT/reference``: the unchanged recipe at the same budget. Each holds ``formic eval`` of that
run's ``model.pt`` on the tables' 16 cells (docs/training.md has the commands; the reference
also with the channel empty, and the blind ``no-pheromones`` run only so, as the paper tested
them). ``formic_eval.tables`` says how a row's relative performance is computed.
``--seeds``: the unchanged recipe's seeds (full budget), whose spread is printed as the noise
scale of one seed. ``--row-seeds``: folders like ROOT holding rows trained again with another seed;
such a row gets a line per seed and one for the mean over its seeds (per scenario, the seeds'
mean food). Where such a folder holds a reference too, every row is relative to the reference
seeds' mean, and their spread is printed as the noise scale at the tables' budget. A row not
evaluated yet says so. The defaults are the
results page's (docs/results.md): ``eval/tables``, every ``eval/recipe-paper/seedS`` and every ``eval/tables-seedS`` folder.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "src"))

from formic_eval.markdown_block import add_block_options, publish  # noqa: E402
from formic_eval.paper import PAPER_TEAMS  # noqa: E402
from formic_eval.tables import (REFERENCE, ROWS, Relative, evaluated_seeds, model_episodes,  # noqa: E402
                                reference_episodes, relative_performance, seed_noise)

BEGIN, END = "<!-- tables:begin (scripts/paper_tables.py) -->", "<!-- tables:end -->"
TITLES = {"I": "Table I: ablations", "II": "Table II: learning and non-learning agents in teams of 32",
          "III": "Table III: field of view"}


def percent(mean: float, std: float) -> str:
    return f"{mean:.1f}% ± {std:.1f}%"


def shown(path: Path) -> str:
    """A path as the block prints it: relative to the repository where it lies inside."""
    path = Path(path)
    return path.resolve().relative_to(ROOT).as_posix() if path.resolve().is_relative_to(ROOT) else str(path)


def row_line(label: str, found: Relative, paper: str) -> str:
    teams = " | ".join(f"{found.by_team[n]:.0f}%" if n in found.by_team else "–" for n in PAPER_TEAMS)
    verdicts = " / ".join(map(str, found.verdicts))
    return f"| {label} | {percent(found.mean, found.std)} | {paper} | {teams} | {found.cells} | {verdicts} |"


def reference_words(folders: list[Path]) -> str:
    if len(folders) == 1:
        return f"`{shown(folders[0])}`"
    names = ", ".join(f"`{shown(folder)}`" for folder in folders)
    return f"the reference row's mean over its {len(folders)} seeds ({names}; per scenario, the seeds' mean food)"


def tables(root: Path, seeds: list[Path], row_seeds: list[Path]) -> list[str]:
    reference_roots = [folder for folder in [root, *row_seeds] if model_episodes(folder / REFERENCE, "")] or [root]
    reference = reference_episodes(reference_roots)
    lines = [f"Relative to {reference_words([folder / REFERENCE for folder in reference_roots])} on the same "
             "scenarios: per cell (infinite resources with and without 3 wipeouts, 0% and 5% obstacles, "
             "16/32/64/128 agents; 128x128, 1024 steps) the row's food over the reference's, then the mean ± "
             "sample std over the cells, as the paper computed Table I; and the cells where the row is behind "
             "the reference, level with it or ahead, by the 95% interval of the paired food difference on the "
             "same scenarios."]
    noise = seed_noise(seeds)
    if noise is not None:
        lines.append("")
        lines.append(f"Noise scale of one seed (the unchanged recipe's {len(seeds)} seeds, each over their mean, "
                     f"{noise.cells} seed-cells): ± {noise.std:.1f}%.")
    if len(reference_roots) > 1:
        noise = seed_noise([folder / REFERENCE for folder in reference_roots])
        lines.append("")
        lines.append(f"At the tables' budget (the reference row's {len(reference_roots)} seeds, each over their "
                     f"mean, {noise.cells} seed-cells): ± {noise.std:.1f}%.")
    for table, title in TITLES.items():
        lines += ["", f"#### {title}", "",
                  "| row | ours | paper | " + " | ".join(f"{n} agents" for n in PAPER_TEAMS)
                  + " | cells | behind / level / ahead |",
                  "|---|---|---|" + "---|" * (len(PAPER_TEAMS) + 2)]
        for row in (r for r in ROWS if r.table == table):
            found = relative_performance(reference, row, [root])
            paper = f"{row.paper[0]:.2f}% ± {row.paper[1]:.2f}%"  # as published
            if found is None:
                lines.append(f"| {row.label} | not evaluated yet ({shown(root / row.switch)}) | {paper} | "
                             + " | ".join("–" for _ in PAPER_TEAMS) + " | 0 | – |")
                continue
            lines.append(row_line(row.label, found, paper))
            others = evaluated_seeds(row_seeds, row)
            for folder in others:
                lines.append(row_line(f"↳ another seed: `{shown(folder)}`",
                                      relative_performance(reference, row, [folder]), ""))
            if others:
                lines.append(row_line(f"↳ mean over its {len(others) + 1} seeds",
                                      relative_performance(reference, row, [root, *others]), ""))
    return lines


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("root", type=Path, nargs="?", default=ROOT / "eval" / "tables",
                        help="the folder of the rows' evaluation folders")
    parser.add_argument("--seeds", nargs="*", type=Path, default=sorted(ROOT.glob("eval/recipe-paper/seed*")),
                        help="eval folders of the unchanged recipe's seeds (the noise scale)")
    parser.add_argument("--row-seeds", nargs="*", type=Path, default=sorted(ROOT.glob("eval/tables-seed*")),
                        help="folders like ROOT holding rows (and the reference) trained with other seeds")
    add_block_options(parser, "tables")
    args = parser.parse_args()
    try:
        lines = tables(args.root, args.seeds, args.row_seeds)
    except ValueError as exc:
        sys.exit(f"paper_tables: {exc}")
    return publish(lines, BEGIN, END, args, "scripts/paper_tables.py")


if __name__ == "__main__":
    sys.exit(main())
