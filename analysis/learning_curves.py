"""Learning curves of one or more training stages, read from their TensorBoard logs, as one PNG.

Stages are drawn one after the other on a common episode axis (a stage's episodes continue
where the previous one's ended), so a model trained in stages shows as one curve:

    .venv/bin/python analysis/learning_curves.py models/training/paper-ref models/training/paper-crowd \
        models/training/paper-feedback models/training/paper-feedback-nonlearning models/training/paper-novalid \
        --until paper-crowd=328 --until paper-feedback-nonlearning=208 --until paper-novalid=496 \
        --out models/formic_paper_curves.png

With ``--overlay`` every run starts at episode 0 and the food panel shows each run's mean over
its training worlds: runs of one recipe with one switch changed (the Table I ablations) side by side.
"""

from __future__ import annotations

from pathlib import Path

import click
import matplotlib
import numpy as np

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402

from formic_trainer.scalars import read_scalars  # noqa: E402

PANELS = (("train/food_env0", "train/food_env1", "train/food_env2", "train/food_env3"),
          ("train/entropy",), ("train/valid_accuracy",), ("train/filter_probability", "train/highway_intensity"))
SCHEDULES = {"train/filter_probability", "train/highway_intensity"}  # drawn as they are, not smoothed
FOOD_MEAN = "train/food_mean_of_worlds"


def mean_over_worlds(series: dict[str, list[tuple[int, float]]]) -> list[tuple[int, float]]:
    """Food averaged over the training worlds, at the episodes every world logged."""
    worlds = [dict(series[tag]) for tag in PANELS[0] if tag in series]
    common = sorted(set.intersection(*(set(w) for w in worlds))) if worlds else []
    return [(step, float(np.mean([w[step] for w in worlds]))) for step in common]


def stages(run_dirs: tuple[Path, ...], until: dict[str, int], overlay: bool = False
           ) -> list[tuple[str, int, dict[str, list[tuple[int, float]]]]]:
    """Each run's name, the episode its curve starts at and its series (cut at ``until[name]``):
    one after the other (a stage starts at the last episode the previous one drew), or all at 0
    with ``overlay`` (plus the food mean over worlds)."""
    out, offset = [], 0
    for run_dir in run_dirs:
        series = read_scalars(run_dir)
        if run_dir.name in until:
            series = {tag: [(s, v) for s, v in points if s <= until[run_dir.name]] for tag, points in series.items()}
        if overlay:
            series[FOOD_MEAN] = mean_over_worlds(series)
        out.append((run_dir.name, offset, series))
        drawn = [points[-1][0] for tags in PANELS for tag in tags if (points := series.get(tag))]
        if not overlay:
            offset += max(drawn, default=0)
    return out


@click.command()
@click.argument("run_dirs", nargs=-1, required=True, type=click.Path(exists=True, file_okay=False, path_type=Path))
@click.option("--out", required=True, type=click.Path(dir_okay=False))
@click.option("--smooth", default=10, show_default=True, help="Moving-average window (logged points).")
@click.option("--overlay", is_flag=True,
              help="Draw every run from episode 0 (comparison), not one after the other (stages).")
@click.option("--until", "untils", multiple=True, metavar="RUN=EPISODE",
              help="Draw run RUN (its directory's name) only up to EPISODE: the part of a stage a model used.")
def main(run_dirs: tuple[Path, ...], out: str, smooth: int, overlay: bool, untils: tuple[str, ...]) -> None:
    """Draw food per world, entropy, valid-action accuracy and the filter/highway schedules."""
    try:
        until = {name: int(episode) for name, episode in (item.split("=") for item in untils)}
    except ValueError as exc:
        raise click.BadParameter("expected RUN=EPISODE", param_hint="--until") from exc
    panels = ((FOOD_MEAN,), *PANELS[1:]) if overlay else PANELS
    fig, axes = plt.subplots(len(panels), 1, figsize=(9, 11), sharex=True)
    for name, offset, series in stages(run_dirs, until, overlay):
        for ax, tags in zip(axes, panels):
            for tag in tags:
                points = series.get(tag, [])
                if not points:
                    continue
                steps = [offset + s for s, _ in points]
                values = [v for _, v in points]
                window = 1 if tag in SCHEDULES else max(1, min(smooth, len(values)))
                totals = np.cumsum([0.0, *values])
                starts = np.maximum(np.arange(len(values)) - window + 1, 0)
                smoothed = (totals[1:] - totals[starts]) / (np.arange(len(values)) + 1 - starts)
                ax.plot(steps, smoothed, label=f"{name}: {tag.split('/')[-1]}")
            if not overlay:
                ax.axvline(offset, color="grey", linewidth=0.5)
    for ax, tags in zip(axes, panels):
        ax.set_ylabel(", ".join(t.split("/")[-1] for t in tags), fontsize=8)
        if ax.get_legend_handles_labels()[0]:  # a panel no run logged stays without a legend
            ax.legend(fontsize=6, ncol=2)
    axes[-1].set_xlabel("training episode" if overlay else "training episode (all stages)")
    fig.tight_layout()
    fig.savefig(out, dpi=110)
    click.echo(f"wrote {out}")


if __name__ == "__main__":
    main()
