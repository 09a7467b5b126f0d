"""A recipe's seeds on the test set as markdown, for ``scripts/seeds_table.py`` and
``formic eval --report --seed-eval``: per Fig. 5 cell each seed's mean food, the mean and the
IQM over seeds, the paired comparison over seeds with each baseline, then the aggregate over the
published cells, the collapse rate and the issue's three targets, each met or missed."""

from __future__ import annotations

import numpy as np

from .paper import RIVALS, setting_title
from .seed_stats import BOOTSTRAP_SEED, COLLAPSE_RATIO, REPLICATES, collapsed
from .seeds import SeedsStudy, fig5_settings, published_food

PAPER_RATIO_TARGET = 0.9  # the mean over seeds against the paper's ForMIC, in every published cell
AHEAD_TARGET, AHEAD_OF = 20, "csaf11"  # cells (of 24) where the mean over seeds is ahead of C-SAF-11
TITLES = dict(RIVALS)


def cell_name(setting: tuple) -> str:
    _, agents, obstacles, env, _ = setting
    return f"{setting_title(env, obstacles)}, {agents} agents"


def test_table(result: SeedsStudy) -> list[str]:
    """One row per Fig. 5 cell that some seed played."""
    if not result.cells:
        return ["(no test episodes of these seeds yet: scripts/eval_model.sh)"]
    names = result.names
    lines = ["| setting | agents | " + " | ".join(names) + " | mean [95%] | IQM [95%] | paper | mean/paper | "
             + " | ".join(f"− {title} over seeds, t [95%] | bootstrap [95%]" for _, title in RIVALS) + " |",
             "|---|---|" + "---|" * (len(names) + 4 + 2 * len(RIVALS))]
    previous = None
    for cell in result.cells:
        _, agents, obstacles, env, _ = cell.setting
        title = setting_title(env, obstacles)
        row = [title if title != previous else "", str(agents),
               *(f"{cell.foods[s]:.0f}" if s in cell.foods else "–" for s in names),
               cell.mean.text(), cell.iqm.text(), f"{cell.paper:.0f}" if cell.paper else "–",
               f"{cell.mean.value / cell.paper:.2f}" if cell.paper else "–"]
        for algorithm, _ in RIVALS:
            versus = cell.versus.get(algorithm)
            row += ([f"{versus.t.text(signed=True)} {versus.verdict}", versus.bootstrap.text(signed=True)]
                    if versus else ["–", "–"])
        lines.append("| " + " | ".join(row) + " |")
        previous = title
    return lines


def method_line(result: SeedsStudy) -> str:
    seeds = f"{len(result.names)} seed{'s' if len(result.names) != 1 else ''}"
    return (f"Intervals are over the {seeds}, not over scenarios. Mean and IQM (interquartile "
            f"mean): 95% stratified bootstrap ({REPLICATES:,} replicates, generator seed {BOOTSTRAP_SEED}). "
            "Against a baseline: each seed's paired mean difference on the cell's scenarios, then a t interval "
            "over seeds (its verdict: ahead, level or behind) and a bootstrap one.")


def aggregate_line(result: SeedsStudy) -> str:
    if result.paper_ratio is None:
        return "ForMIC / the paper: no published cell that every seed played."
    ratio = result.paper_ratio
    per_seed = ", ".join(f"{name} {value:.2f}" for name, value in result.seed_paper_ratio().items())
    return (f"ForMIC / the paper over the {len(result.paper_cells)} published cells every seed played (each seed's "
            f"mean food in a cell divided by the paper's): mean {ratio.mean.text(2)}, IQM {ratio.iqm.text(2)}; "
            f"per seed: {per_seed}.")


def collapse_line(result: SeedsStudy) -> str:
    foods = result.collapse_foods
    down = collapsed(list(foods.values()))
    median = float(np.median(list(foods.values())))
    which = ", ".join(f"{name} {food:.1f} ({food / median:.2f} x)"
                      for (name, food), d in zip(foods.items(), down) if d)
    return (f"Collapse rate: {int(down.sum())} of {len(down)} seeds ({down.mean():.0%}) below {COLLAPSE_RATIO} x "
            f"the median seed's {result.collapse_source} ({median:.1f})" + (f": {which}." if which else "."))


def collapse_target(result: SeedsStudy) -> str:
    """No seed collapses: met, or which seeds did and how far the lowest is from the line."""
    foods = result.collapse_foods
    median = float(np.median(list(foods.values())))
    lowest = min(foods, key=foods.get)
    share = foods[lowest] / median
    down = [name for name, d in zip(foods, collapsed(list(foods.values()))) if d]
    if not down:
        return f"met: the lowest seed, {lowest}, is at {share:.2f} x the median"
    return (f"missed: {len(down)} of {len(foods)} seeds collapsed ({', '.join(down)}); the lowest, {lowest}, "
            f"is at {share:.2f} x the median, {COLLAPSE_RATIO - share:.2f} short")


def paper_target(result: SeedsStudy) -> str:
    """The mean over seeds against the paper in every published cell: met, or the cells short."""
    ratios = sorted((cell.mean.value / cell.paper, cell_name(cell.setting)) for cell in result.cells if cell.paper)
    if not ratios:
        return "not judged: no published cell evaluated"
    short = [f"{name} ({ratio:.2f} x)" for ratio, name in ratios if ratio < PAPER_RATIO_TARGET]
    text = (f"missed in {len(short)} of {len(ratios)} published cells: {'; '.join(short)}; the lowest is "
            f"{PAPER_RATIO_TARGET - ratios[0][0]:.2f} short" if short
            else f"met in all {len(ratios)}: the lowest is {ratios[0][0]:.2f} x ({ratios[0][1]})")
    total = sum(published_food(setting) is not None for setting in fig5_settings())
    return text + (f" (only {len(ratios)} of the {total} published cells evaluated)" if len(ratios) < total else "")


def ahead_target(result: SeedsStudy) -> str:
    """Ahead of C-SAF-11 by the t interval over seeds in enough cells: met or how many short."""
    verdicts = [cell.versus[AHEAD_OF].verdict for cell in result.cells if AHEAD_OF in cell.versus]
    count = {v: verdicts.count(v) for v in ("ahead", "level", "behind")}
    judged = (f"ahead in {count['ahead']}, level in {count['level']}, behind in {count['behind']} "
              f"of {len(verdicts)} cells")
    text = (f"met: {judged}" if count["ahead"] >= AHEAD_TARGET
            else f"missed: {judged}, {AHEAD_TARGET - count['ahead']} short")
    cells = len(fig5_settings())
    return text + (f" (only {len(verdicts)} of the {cells} cells evaluated)" if len(verdicts) < cells else "")


def target_lines(result: SeedsStudy) -> list[str]:
    """The issue's three targets, each met or missed and by how much."""
    return [f"- No seed collapses (each ≥ {COLLAPSE_RATIO} x the median seed's {result.collapse_source}): "
            f"{collapse_target(result)}.",
            f"- Mean over seeds ≥ {PAPER_RATIO_TARGET} x the paper's ForMIC in each published Fig. 5 cell: "
            f"{paper_target(result)}.",
            f"- Ahead of {TITLES[AHEAD_OF]} in ≥ {AHEAD_TARGET} of {len(fig5_settings())} cells by the t interval "
            f"over seeds: {ahead_target(result)}."]


def seeds_report(result: SeedsStudy) -> list[str]:
    """The test table, how its intervals are made, the aggregate, the collapse rate and the targets."""
    if not result.cells:
        return test_table(result)
    return [*test_table(result), "", method_line(result), "", aggregate_line(result), "", collapse_line(result),
            "", "Targets (no collapse; at least 0.9x the paper in each published cell; ahead of C-SAF-11 in at least 20 of 24 cells):", "", *target_lines(result)]
