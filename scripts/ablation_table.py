"""The paper's Table I from our evaluations: one row per trained variant, beside the paper's.

Each row is ``LABEL=EVAL_DIR[:VARIANT]``: the episodes of ``formic eval --out EVAL_DIR`` at the
paper's protocol (128x128, 1024 steps, infinite resources, no obstacles), of the one model
evaluated there, with VARIANT "" (sampling, the default), "greedy" or "no-pheromones". The first
row is the reference the others are relative to, as in the paper. The paper's row of the same
label (formic_eval.paper.PAPER_ABLATION) is printed beside each, with its own ratio.

    .venv/bin/python scripts/ablation_table.py \\
        "full ForMIC=eval/formic_paper_stage1" \\
        "tested without pheromones=eval/formic_paper_stage1:no-pheromones" \\
        "trained and tested without pheromones=eval/ablation_no_pheromones:no-pheromones" \\
        "without curriculum=eval/ablation_no_curriculum"
"""

from __future__ import annotations

import argparse
import statistics
from collections import defaultdict
from pathlib import Path

from formic_eval.paper import PAPER_ABLATION, PAPER_SIZE, PAPER_STEPS, PAPER_TEAMS
from formic_eval.runner import folder_episodes


def row_food(eval_dir: Path, variant: str) -> tuple[dict[int, list[float]], str]:
    """Food per team size of the paper-protocol episodes of one model and variant in ``eval_dir``."""
    food: dict[int, list[float]] = defaultdict(list)
    models = set()
    for episode in folder_episodes(eval_dir):
        if (episode["algorithm"], episode["variant"], episode["size"], episode["steps"], episode["env"],
                episode["obstacles"]) != ("formic", variant, PAPER_SIZE, PAPER_STEPS, "infinite", 0.0):
            continue
        models.add(episode["model"])
        food[episode["agents"]].append(episode["food"])
    if len(models) != 1:
        raise SystemExit(f"{eval_dir} holds {len(models)} models' formic episodes with variant {variant!r}; "
                         "expected exactly one")
    missing = [n for n in PAPER_TEAMS if not food[n]]
    if missing:
        raise SystemExit(f"{eval_dir} has no {variant or 'sampling'} episodes for {missing} agents")
    return food, models.pop()


def standard_error(values: list[float]) -> float:
    return statistics.stdev(values) / len(values) ** 0.5 if len(values) > 1 else float("nan")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("rows", nargs="+", metavar="LABEL=EVAL_DIR[:VARIANT]")
    args = parser.parse_args()
    rows = []
    for spec in args.rows:
        label, sep, where = spec.partition("=")
        if not sep:
            parser.error(f"expected LABEL=EVAL_DIR[:VARIANT], got {spec!r}")
        directory, _, variant = where.partition(":")
        food, model = row_food(Path(directory), variant)
        rows.append((label, food, model))

    reference = {n: statistics.mean(rows[0][1][n]) for n in PAPER_TEAMS}
    paper_reference = PAPER_ABLATION.get(rows[0][0])
    teams = " | ".join(str(n) for n in PAPER_TEAMS)
    counts = sorted({len(food[n]) for _, food, _ in rows for n in PAPER_TEAMS})
    print(f"Food in {PAPER_STEPS} steps, mean ± standard error over {'/'.join(map(str, counts))} "
          "scenarios per team size.")
    print()
    print(f"| variant | model | {teams} | ÷ first row | paper: {teams} | paper ÷ first row |")
    print("|---|---|" + "---:|" * (2 * len(PAPER_TEAMS) + 2))
    for label, food, model in rows:
        means = [statistics.mean(food[n]) for n in PAPER_TEAMS]
        ours = " | ".join(f"{m:.1f} ± {standard_error(food[n]):.1f}" for m, n in zip(means, PAPER_TEAMS))
        ratio = statistics.mean(m / reference[n] for m, n in zip(means, PAPER_TEAMS))
        paper = PAPER_ABLATION.get(label)
        if paper is None:
            paper_cells, paper_ratio = " | ".join("–" for _ in PAPER_TEAMS), "–"
        else:
            paper_cells = " | ".join(f"{v:.0f}" for v in paper)
            paper_ratio = "–" if paper_reference is None else \
                f"{statistics.mean(v / r for v, r in zip(paper, paper_reference)):.2f}"
        print(f"| {label} | `{model}` | {ours} | {ratio:.2f} | {paper_cells} | {paper_ratio} |")


if __name__ == "__main__":
    main()
