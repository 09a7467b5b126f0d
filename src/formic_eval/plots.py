"""Figures like the paper's: food versus team size (Fig. 5), time per step versus team size
(Fig. 6), and food versus time. One set of PNGs per world size and episode length."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from .paper import algorithm_label as _label
from .paper import paper_food

COLOURS = {"formic": "C3", "planner": "C0", "csaf": "C1", "csaf11": "C2", "cardinality": "C4", "random": "C7",
           "csaf-ref": "C5", "csaf11-ref": "C6"}


def _pyplot():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def _line(cell: dict) -> tuple[str, str]:
    return cell["algorithm"], cell["variant"]


def _style(line: tuple[str, str], env: str) -> dict:
    algorithm, variant = line
    return {
        "color": COLOURS.get(algorithm, "k"),
        "linestyle": "--" if env == "wipeout" else ":" if variant else "-",
        "marker": "o",
    }


def _panel(cell: dict) -> tuple[str, float]:
    """Wipeout lines share the infinite panel (dashed), as in the paper's Fig. 5."""
    return ("infinite" if cell["env"] == "wipeout" else cell["env"], cell["obstacles"])


def _team_axis(ax, teams: list[int]) -> None:
    ax.set_xscale("log", base=2)
    ax.set_xticks(teams)
    ax.set_xticklabels([str(t) for t in teams])
    ax.set_xlabel("team size")
    ax.grid(alpha=0.3)


REPORT_FIGURES = "*_s*_t*.png"  # what plot_all names its figures: NAME_sSIZE_tSTEPS.png


def plot_all(cells: list[dict], out: Path) -> list[str]:
    """Every figure for every (size, steps) group of cells; returns the PNG paths."""
    paths = []
    for size, steps in sorted({(c["size"], c["steps"]) for c in cells}):
        group = [c for c in cells if (c["size"], c["steps"]) == (size, steps)]
        for name, plot in (("food_vs_team", plot_food_vs_team), ("time_per_step", plot_time_per_step),
                           ("food_vs_time", plot_food_vs_time)):
            paths.append(plot(group, Path(out) / f"{name}_s{size}_t{steps}.png"))
    return [str(p) for p in paths]


def published_line(points: list[dict]) -> list[tuple[int, float]]:
    """(team size, the paper's food) for the cells of one line that have a published value: drawn
    beside ours so that the figure, like the tables, shows the paper."""
    return [(c["agents"], food) for c in points if (food := paper_food(c)) is not None]


def plot_food_vs_team(cells: list[dict], path: Path) -> Path:
    """Fig. 5: food deposited versus team size, error bars = std over scenarios."""
    plt = _pyplot()
    panels = sorted({_panel(c) for c in cells})
    teams = sorted({c["agents"] for c in cells})
    fig, axes = plt.subplots(1, len(panels), figsize=(5.5 * len(panels), 4.4), squeeze=False)
    for ax, panel in zip(axes[0], panels):
        in_panel = [c for c in cells if _panel(c) == panel]
        for line, env in sorted({(_line(c), c["env"]) for c in in_panel}):
            pts = sorted((c for c in in_panel if (_line(c), c["env"]) == (line, env)), key=lambda c: c["agents"])
            label = _label(pts[0]) + (" (wipeouts)" if env == "wipeout" else "")
            ax.errorbar([c["agents"] for c in pts], [c["food_mean"] for c in pts], yerr=[c["food_std"] for c in pts],
                        capsize=3, label=label, **_style(line, env))
            published = published_line(pts)
            if line == ("formic", "") and published:
                ax.plot(*zip(*published), color="k", marker="x", markersize=8, zorder=3,
                        linestyle=_style(line, env)["linestyle"], label="ForMIC, the paper's" + label[len("ForMIC"):])
        _team_axis(ax, teams)
        ax.set_title(f"{panel[0]} resources, {panel[1] * 100:g}% obstacles")
        ax.set_ylabel("food deposited")
    # one legend for every panel, under them: inside a panel it hid the lines
    legend = {}
    for ax in axes[0]:
        for handle, label in zip(*ax.get_legend_handles_labels()):
            legend.setdefault(label, handle)
    fig.legend(list(legend.values()), list(legend), loc="upper center", bbox_to_anchor=(0.5, 0.0),
               ncol=min(5, len(legend)), fontsize=8, frameon=False)
    size, steps = cells[0]["size"], cells[0]["steps"]
    fig.suptitle(f"Food deposited in {steps} steps, {size}x{size} world (mean ± std)")
    fig.subplots_adjust(top=0.85, wspace=0.25)
    return _save(fig, path)


def plot_time_per_step(cells: list[dict], path: Path) -> Path:
    """Fig. 6: decision time per step for the team and per agent (log scale), averaged over the
    group's environments and obstacle densities, weighted by scenarios."""
    plt = _pyplot()
    teams = sorted({c["agents"] for c in cells})
    fig, axes = plt.subplots(1, 2, figsize=(11, 4.4))
    for line in sorted({_line(c) for c in cells}):
        pts = [c for c in cells if _line(c) == line]
        xs = sorted({c["agents"] for c in pts})
        team_ms = [_weighted([c for c in pts if c["agents"] == n], "step_ms_mean") for n in xs]
        style = _style(line, "infinite")
        axes[0].plot(xs, team_ms, label=_label(pts[0]), **style)
        axes[1].plot(xs, [ms / n for ms, n in zip(team_ms, xs)], label=_label(pts[0]), **style)
    for ax, title in zip(axes, ("whole team", "per agent")):
        _team_axis(ax, teams)
        ax.set_yscale("log")
        ax.set_ylabel("ms per step")
        ax.set_title(f"decision time per step, {title}")
        ax.legend(fontsize=7)
    return _save(fig, path)


def plot_food_vs_time(cells: list[dict], path: Path) -> Path:
    """Mean food deposited after each step: one row per environment/obstacles, one column per team."""
    plt = _pyplot()
    rows = sorted({(c["env"], c["obstacles"]) for c in cells})
    teams = sorted({c["agents"] for c in cells})
    fig, axes = plt.subplots(len(rows), len(teams), figsize=(3.8 * len(teams), 3.0 * len(rows)), squeeze=False)
    fig.subplots_adjust(hspace=0.45, wspace=0.3)
    for i, (env, obstacles) in enumerate(rows):
        for j, n in enumerate(teams):
            ax = axes[i][j]
            for c in cells:
                if (c["env"], c["obstacles"], c["agents"]) == (env, obstacles, n):
                    curve = np.asarray(c["food_curve_mean"])
                    style = _style(_line(c), env) | {"marker": None}
                    ax.plot(np.arange(1, len(curve) + 1), curve, label=_label(c), **style)
            ax.set_title(f"{env}, {obstacles * 100:g}% obst., {n} agents", fontsize=8)
            ax.grid(alpha=0.3)
            if i == len(rows) - 1:
                ax.set_xlabel("step")
            if j == 0:
                ax.set_ylabel("food")
    axes[0][0].legend(fontsize=6)
    return _save(fig, path)


def _weighted(cells: list[dict], key: str) -> float:
    return float(np.average([c[key] for c in cells], weights=[c["n"] for c in cells]))


def _save(fig, path: Path) -> Path:
    import matplotlib.pyplot as plt

    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=100, bbox_inches="tight")
    plt.close(fig)
    return path
