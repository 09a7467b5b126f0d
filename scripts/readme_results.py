#!/usr/bin/env python3
"""The results page's block and the README's summary of it, rebuilt from the evaluation folders
by one command.

    .venv/bin/python scripts/readme_results.py --write docs/results.md README.md   # replace both in place
    .venv/bin/python scripts/readme_results.py --check docs/results.md README.md   # exit 1 if one is stale

Each file named gets the blocks it holds: the full results (``results`` markers, docs/results.md)
and the summary (``summary`` markers, README.md: the first Fig. 5 setting's table and the figure).

The shipped model's episodes come from ``--model-eval`` (its ``formic`` records, every variant);
the baselines' and the planner's from ``--baselines-eval`` (every other algorithm), on the same
stored scenarios. The block holds: food per cell beside the paper's, a figure, and the paired
comparisons (mean of per-scenario differences with 95% intervals, ``formic_eval.paired``):
ForMIC against C-SAF-11 and Cardinality-MR, the cost of an empty pheromone channel, of the
out-of-distribution trails and of wipeouts on the same layouts; then the 32x32 and 64x64 worlds
(food per cell, ForMIC against each rival paired), once the model has played them. Every number
names its model by file and digest.
"""

from __future__ import annotations

import argparse
import os
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "src"))

from formic_eval.markdown_block import write_or_check  # noqa: E402
from formic_eval.matrix import file_digest  # noqa: E402
from formic_eval.paired import PairedDifference, compare, layout_key  # noqa: E402
from formic_eval.paper import (FIG5_SETTINGS, PAPER_SIZE, PAPER_STEPS, PAPER_TEAMS, RIVALS,  # noqa: E402
                               algorithm_label, paper_food, setting_title, test_set_episodes)
from formic_eval.plots import plot_food_vs_team  # noqa: E402
from formic_eval.results import aggregate  # noqa: E402
from formic_eval.runner import folder_episodes  # noqa: E402

BEGIN, END = "<!-- results:begin (scripts/readme_results.py) -->", "<!-- results:end -->"
SUMMARY_BEGIN, SUMMARY_END = "<!-- summary:begin (scripts/readme_results.py) -->", "<!-- summary:end -->"
# rows of the main table, in order: (algorithm, variant)
ROWS = [("formic", ""), ("formic", "no-pheromones"), ("planner", ""), ("csaf11", ""), ("csaf", ""),
        ("cardinality", ""), ("csaf11-ref", ""), ("csaf-ref", ""), ("random", "")]

# the reference code's plots' smaller worlds (infinite resources, no obstacles, 1024 steps)
SMALL_SIZES = (32, 64)

# the paper's out-of-distribution pheromone dynamics (formic eval --variant), against standard trails
TRAIL_VARIANTS = [("trails-flat", "trails without gradient"), ("trails-noisy", "trails with a noisy gradient"),
                  ("trails-random", "trails of random concentration 0.2-1")]


def percent_less(d: PairedDifference) -> str:
    """``d`` is changed minus base: how much less the changed one deposits, in % of base."""
    mean, low, high = d.percent()
    return f"{-mean:.0f}% [{-high:.0f}, {-low:.0f}] (n={d.n})"


def main_table(cells: list[dict], settings=FIG5_SETTINGS) -> list[str]:
    by_key = {(c["algorithm"], c["variant"], c["env"], c["obstacles"], c["agents"]): c for c in cells}
    lines = ["| setting | algorithm | " + " | ".join(f"{n} agents" for n in PAPER_TEAMS) + " |",
             "|---|---|" + "---|" * len(PAPER_TEAMS)]
    for env, obstacles in settings:
        first = True
        for algorithm, variant in ROWS:
            row = [by_key.get((algorithm, variant, env, obstacles, n)) for n in PAPER_TEAMS]
            if not any(row):
                continue
            label = next(algorithm_label(c) for c in row if c)
            if algorithm == "formic" and not variant:
                label = f"**{label}**"
            counts = sorted({c["n"] for c in row if c})
            setting = f"{setting_title(env, obstacles)} (n={'/'.join(map(str, counts))})" if first else ""
            lines.append(f"| {setting} | {label} | " + " | ".join(food_cell(c) for c in row) + " |")
            first = False
    return lines


def food_cell(cell: dict | None) -> str:
    if cell is None:
        return "–"
    text = f"{cell['food_mean']:.0f} ± {cell['food_std']:.0f}"
    if cell.get("paper_food") is not None:
        text += f" ({cell['paper_food']:.0f})"
    if cell.get("food_ratio_to_planner") is not None and cell["algorithm"] != "planner":
        text += f" [{cell['food_ratio_to_planner']:.2f}]"
    return text


def paired_table(model: list[dict], baselines: list[dict]) -> list[str]:
    """One row per setting and comparison; one column per team size."""
    header = ["| setting | comparison | " + " | ".join(f"{n} agents" for n in PAPER_TEAMS) + " |",
              "|---|---|" + "---|" * len(PAPER_TEAMS)]
    lines = []
    for env, obstacles in FIG5_SETTINGS:
        ours = test_set_episodes(model, "formic", env=env, obstacles=obstacles)
        if not ours:
            continue
        rows: list[tuple[str, dict]] = []
        for name, title in RIVALS:
            found = compare(ours, test_set_episodes(baselines, name, env=env, obstacles=obstacles))
            rows.append((f"ForMIC − {title} (food)", {k[1]: d.food_text() for k, d in found.items()}))
        empty = compare(test_set_episodes(model, "formic", "no-pheromones", env=env, obstacles=obstacles), ours)
        rows.append(("pheromone channel empty: less food", {k[1]: percent_less(d) for k, d in empty.items()}))
        for variant, what in TRAIL_VARIANTS:  # the paper's out-of-distribution tests (§V), where run
            changed = compare(test_set_episodes(model, "formic", variant, env=env, obstacles=obstacles), ours)
            rows.append((f"{what}: less food", {k[1]: percent_less(d) for k, d in changed.items()}))
        if env == "wipeout":
            plain = test_set_episodes(model, "formic", env="infinite", obstacles=obstacles)
            cost = compare(ours, plain, key=layout_key)
            rows.append(("3 wipeouts: less food than the same layouts without",
                         {k[1]: percent_less(d) for k, d in cost.items()}))
        title = setting_title(env, obstacles)
        for label, by_team in rows:
            if by_team:
                lines.append(f"| {title} | {label} | " + " | ".join(by_team.get(n, "–") for n in PAPER_TEAMS) + " |")
                title = ""
    return header + lines if lines else []


def small_world_episodes(records: list[dict]) -> list[dict]:
    """The episodes (as trained, no test variant) in the reference code's smaller worlds."""
    return [r for r in records if r["size"] in SMALL_SIZES and r["steps"] == PAPER_STEPS and r["variant"] == ""
            and r["env"] == "infinite" and r["obstacles"] == 0]


def small_world_tables(model: list[dict], baselines: list[dict]) -> list[str]:
    """Food per cell in the 32x32 and 64x64 worlds, then ForMIC against each rival paired per
    scenario; nothing until the model has played them."""
    ours = small_world_episodes(model)
    if not ours:
        return []
    sizes = sorted({r["size"] for r in ours})
    rivals = [r for r in small_world_episodes(baselines) if r["size"] in sizes]
    by_key = {(c["algorithm"], c["size"], c["agents"]): c for c in aggregate(ours + rivals)}
    lines = ["| world | algorithm | " + " | ".join(f"{n} agents" for n in PAPER_TEAMS) + " |",
             "|---|---|" + "---|" * len(PAPER_TEAMS)]
    paired = ["| world | comparison | " + " | ".join(f"{n} agents" for n in PAPER_TEAMS) + " |",
              "|---|---|" + "---|" * len(PAPER_TEAMS)]
    for size in sizes:
        first = True
        for algorithm, variant in ROWS:
            row = [by_key.get((algorithm, size, n)) for n in PAPER_TEAMS] if not variant else []
            if not any(row):
                continue
            label = next(algorithm_label(c) for c in row if c)
            label = f"**{label}**" if algorithm == "formic" else label
            counts = sorted({c["n"] for c in row if c})
            world = f"{size}x{size} (n={'/'.join(map(str, counts))})" if first else ""
            lines.append(f"| {world} | {label} | " + " | ".join(food_cell(c) for c in row) + " |")
            first = False
        world = f"{size}x{size}"
        for name, title in RIVALS:
            found = compare([r for r in ours if r["size"] == size],
                            [r for r in rivals if r["algorithm"] == name and r["size"] == size])
            by_team = {k[1]: d.food_text() for k, d in found.items()}
            if by_team:
                paired.append(f"| {world} | ForMIC − {title} (food) | "
                              + " | ".join(by_team.get(n, "–") for n in PAPER_TEAMS) + " |")
                world = ""
    return ["In the reference code's smaller worlds (infinite resources, no obstacles, 1024 steps; "
            "mean ± std over the n scenarios, [food ÷ the planner's]):", "", *lines, "", *paired]


def paper_ratio_line(cells: list[dict]) -> list[str]:
    """ForMIC's food over the paper's ForMIC per cell (the paper gives no spread: a plain ratio)."""
    lines = []
    for env, obstacles in FIG5_SETTINGS:
        ratios = []
        for n in PAPER_TEAMS:
            cell = next((c for c in cells if (c["algorithm"], c["variant"], c["env"], c["obstacles"], c["agents"])
                         == ("formic", "", env, obstacles, n)), None)
            published = paper_food(cell) if cell else None
            ratios.append(f"{cell['food_mean'] / published:.2f}" if cell and published else "–")
        if any(r != "–" for r in ratios):
            lines.append(f"| {setting_title(env, obstacles)} | " + " | ".join(ratios) + " |")
    if not lines:
        return []
    return (["| setting | " + " | ".join(f"{n} agents" for n in PAPER_TEAMS) + " |",
             "|---|" + "---|" * len(PAPER_TEAMS)] + lines)


def evidence(model_eval: Path, baselines_eval: Path, model_file: Path) -> tuple[list[dict], list[dict], str]:
    """The shipped model's episodes, every other algorithm's, and the model's digest (checked:
    the model's folder holds episodes of ``model_file`` only)."""
    model = [r for r in folder_episodes(model_eval) if r["algorithm"] == "formic"]
    baselines = [r for r in folder_episodes(baselines_eval) if r["algorithm"] != "formic"]
    digests = sorted({r["model"] for r in model})
    if digests != [file_digest(model_file)]:
        raise SystemExit(f"{model_eval} holds episodes of model(s) {digests}, not of {model_file} "
                         f"({file_digest(model_file)}): evaluate the shipped model there first")
    return model, baselines, digests[0]


def paper_cells(model: list[dict], baselines: list[dict]) -> list[dict]:
    """Every algorithm's cells in the paper's world size and episode length."""
    return aggregate([r for r in model + baselines if r["size"] == PAPER_SIZE and r["steps"] == PAPER_STEPS])


def rel(path: Path) -> str:
    return Path(path).resolve().relative_to(ROOT).as_posix()


def provenance(model_file: Path, digest: str, model_eval: Path, baselines_eval: Path) -> str:
    return (f"ForMIC here is `{rel(model_file)}` (digest `{digest}`), its episodes in `{rel(model_eval)}/`; "
            f"every other algorithm's in `{rel(baselines_eval)}/`, on the same stored scenarios. Food deposited in "
            f"{PAPER_STEPS} steps on {PAPER_SIZE}x{PAPER_SIZE} worlds, mean ± std over the n scenarios; "
            "(the paper's value); "
            "[food ÷ the centralized planner's on the same scenarios].")


def block(model: list[dict], baselines: list[dict], cells: list[dict], head: str, figure_link: str) -> list[str]:
    """The results page's block: every Fig. 5 cell, the figure, the ratios to the paper, the paired
    comparisons and the smaller worlds."""
    small_worlds = small_world_tables(model, baselines)
    return [
        head,
        "",
        *main_table(cells),
        "",
        f"![food versus team size]({figure_link})",
        "",
        "ForMIC's food divided by the paper's ForMIC (the paper's values are read from its plots, ±~10):",
        "",
        *paper_ratio_line(cells),
        "",
        "Paired comparisons: the mean over scenarios of the per-scenario difference, [its 95% interval] "
        "(Student's t over the n pairs). A difference whose interval excludes 0 is a difference; "
        "\"less food\" is that difference as a share of the first one's mean.",
        "",
        *paired_table(model, baselines),
        *([""] + small_worlds if small_worlds else []),
    ]


def summary(cells: list[dict], head: str, figure_link: str) -> list[str]:
    """The README's summary: the first Fig. 5 setting's table and the figure."""
    return [head, "", *main_table(cells, FIG5_SETTINGS[:1]), "", f"![food versus team size]({figure_link})"]


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--model-eval", type=Path, default=ROOT / "eval" / "recipe-paper" / "seed3")
    parser.add_argument("--baselines-eval", type=Path, default=ROOT / "eval" / "readme")
    parser.add_argument("--model", type=Path, default=ROOT / "models" / "formic_recipe.pt")
    parser.add_argument("--figure", type=Path,
                        default=ROOT / "eval" / "recipe-paper" / "seed3" / "readme_food_vs_team.png")
    action = parser.add_mutually_exclusive_group()
    action.add_argument("--write", type=Path, nargs="+", metavar="FILE",
                        help="replace the results and summary blocks these files hold")
    action.add_argument("--check", type=Path, nargs="+", metavar="FILE",
                        help="exit 1 if a block these files hold is stale")
    args = parser.parse_args()
    model, baselines, digest = evidence(args.model_eval, args.baselines_eval, args.model)
    cells = paper_cells(model, baselines)
    if args.check is None:
        plot_food_vs_team([c for c in cells if c["variant"] == ""], args.figure)
    head = provenance(args.model, digest, args.model_eval, args.baselines_eval)
    targets = args.write or args.check
    if targets is None:
        print("\n".join(block(model, baselines, cells, head, rel(args.figure))))
        return 0
    status = 0
    for target in targets:
        text = target.read_text()
        link = os.path.relpath(args.figure.resolve(), target.resolve().parent)
        blocks = [(BEGIN, END, lambda: block(model, baselines, cells, head, link)),
                  (SUMMARY_BEGIN, SUMMARY_END, lambda: summary(cells, head, link))]
        found = [(begin, end, lines) for begin, end, lines in blocks if begin in text]
        if not found:
            raise SystemExit(f"{target} holds no block of scripts/readme_results.py ({BEGIN} or {SUMMARY_BEGIN})")
        for begin, end, lines in found:
            status |= write_or_check(target, begin, end, "\n".join([begin, *lines(), end]),
                                     check=args.check is not None, command="scripts/readme_results.py")
    return status


if __name__ == "__main__":
    sys.exit(main())
