#!/usr/bin/env python3
"""The recipe's seeds side by side: which one ships (validation) and how they all do (test).

    .venv/bin/python scripts/seeds_table.py \\
        --runs models/training/recipe-paper/seed1 models/training/recipe-paper/seed2 \\
        --evals eval/recipe-paper/seed1 eval/recipe-paper/seed2 --baselines eval/readme

``--runs``: each seed's ``formic train --recipe`` directory (its ``selection.json``). ``--evals``:
each seed's ``scripts/eval_model.sh`` folder, in the same order (a missing one leaves that
seed out of the test table). ``--baselines``: the baselines' episodes on the same scenarios
(``scripts/eval_readme.sh``). Prints markdown: the validation table and the seed chosen on
it, then per Fig. 5 cell each seed's food, the mean ± std over seeds beside the paper's ForMIC,
and the mean over seeds against C-SAF-11 and Cardinality-MR, paired per scenario (95%
intervals), with how many seeds are ahead on their own. Without ``--runs``: every finished seed
(``models/training/recipe-paper/seedS`` with its ``selection.json``) and its
``eval/recipe-paper/seedS`` folder, the README's block:

    .venv/bin/python scripts/seeds_table.py --write README.md   # replace the block in place
    .venv/bin/python scripts/seeds_table.py --check README.md   # exit 1 if the README is stale
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "src"))

from formic_eval.markdown_block import add_block_options, publish  # noqa: E402
from formic_eval.paired import compare  # noqa: E402
from formic_eval.paper import (FIG5_SETTINGS, PAPER_SIZE, PAPER_STEPS, PAPER_TEAMS, RIVALS, paper_food,  # noqa: E402
                               setting_title, test_set_episodes)
from formic_eval.runner import folder_episodes  # noqa: E402
from formic_eval.seeds import SeedValidation, mean_over_seeds, seed_means, shipped_seed, spread  # noqa: E402



BEGIN, END = "<!-- seeds:begin (scripts/seeds_table.py) -->", "<!-- seeds:end -->"
RUNS = ROOT / "models" / "training" / "recipe-paper"
EVALS = ROOT / "eval" / "recipe-paper"


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


def test_table(per_seed: dict[str, list[dict]], baselines: dict[str, list[dict]]) -> list[str]:
    names = list(per_seed)
    means = seed_means(per_seed)
    pooled = mean_over_seeds(per_seed)
    versus = {algorithm: compare(pooled, records) for algorithm, records in baselines.items()}
    alone = {algorithm: {name: compare(per_seed[name], records) for name in names}
             for algorithm, records in baselines.items()}
    header = ["| setting | agents | " + " | ".join(names) + " | mean ± std | paper | mean/paper | "
              + " | ".join(f"seeds' mean − {title} [95%] | seeds ahead" for _, title in RIVALS) + " |",
              "|---|---|" + "---|" * (len(names) + 3 + 2 * len(RIVALS))]
    lines = []
    for env, obstacles in FIG5_SETTINGS:
        title = setting_title(env, obstacles)
        for n in PAPER_TEAMS:
            setting = (PAPER_SIZE, n, obstacles, env, PAPER_STEPS)
            by_seed = means.get(setting, {})
            if not by_seed:
                continue
            mean, std = spread(list(by_seed.values()))
            published = paper_food({"algorithm": "formic", "variant": "", "size": PAPER_SIZE, "steps": PAPER_STEPS,
                                    "agents": n, "env": env, "obstacles": obstacles})
            row = [title, str(n), *(f"{by_seed[s]:.0f}" if s in by_seed else "–" for s in names),
                   f"{mean:.0f} ± {std:.0f}", f"{published:.0f}" if published else "–",
                   f"{mean / published:.2f}" if published else "–"]
            for algorithm, _ in RIVALS:
                d = versus[algorithm].get(setting)
                ahead = [alone[algorithm][s].get(setting) for s in names]
                row.append(d.food_text() if d else "–")
                counted = [x for x in ahead if x is not None]
                row.append(f"{sum(x.mean > 0 for x in counted)} of {len(counted)}" if counted else "–")
            lines.append("| " + " | ".join(row) + " |")
            title = ""
    return header + lines if lines else ["(no test episodes of these seeds yet: scripts/eval_model.sh)"]


def tables(runs: list[Path], evals: list[Path], baselines_folder: Path) -> list[str]:
    """The validation table and the seed that ships, then the test table."""
    validations = [SeedValidation.load(run) for run in runs]
    per_seed = {v.name: episodes(folder, "formic") for v, folder in zip(validations, evals)}
    per_seed = {name: records for name, records in per_seed.items() if records}
    baselines = {algorithm: episodes(baselines_folder, algorithm) for algorithm, _ in RIVALS}
    return ["#### Validation", "", *validation_table(validations), "",
            "#### Test (Fig. 5's cells)", "", *test_table(per_seed, baselines)]


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--runs", nargs="+", type=Path, help="each seed's recipe run directory")
    parser.add_argument("--evals", nargs="*", type=Path, default=[],
                        help="each seed's eval_model.sh folder, same order")
    parser.add_argument("--baselines", type=Path, default=ROOT / "eval" / "readme", help="the baselines' eval folder")
    add_block_options(parser, "seeds")
    args = parser.parse_args()
    if args.runs is None:
        args.runs = sorted(run for run in RUNS.glob("seed*") if (run / "selection.json").is_file())
        args.evals = [EVALS / run.name for run in args.runs]
    if args.evals and len(args.evals) != len(args.runs):
        parser.error(f"--evals names {len(args.evals)} folders for {len(args.runs)} runs")
    try:
        lines = tables(args.runs, args.evals, args.baselines)
    except ValueError as exc:
        sys.exit(f"seeds_table: {exc}")
    return publish(lines, BEGIN, END, args, "scripts/seeds_table.py")


if __name__ == "__main__":
    sys.exit(main())
