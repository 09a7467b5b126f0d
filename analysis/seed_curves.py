"""Every seed of one recipe on one figure, read from the committed training logs alone.

Each seed's ``seedS.log`` (what ``formic train --recipe`` prints) has one line per episode set:
its stage, episode, food (the mean over the set's worlds), entropy, valid-action accuracy and
approximate KL. A run resumed after a kill replays the episodes since its last checkpoint, so a
later line for the same stage and episode replaces the earlier one. Stages are laid end to end
per seed (a stage that ended on its clock is shorter), their lengths from each stage's
``progress.json`` where it has finished; a stage with no line in the log (seeds that started
from another run's stage) leaves a gap. Prints, per seed and stage, the episodes, the food of its
last 40 episodes and its deepest fall: the lowest 40-episode mean food after the stage's best,
as a share of that best (a collapse shows as a fall that does not come back).

    .venv/bin/python analysis/seed_curves.py models/training/recipe-paper-v6 \
        --stages-from models/training/recipe-paper-v3 --out docs/paper_v6_seeds.png
"""

from __future__ import annotations

import json
import re
from dataclasses import dataclass, field
from pathlib import Path

import click
import matplotlib
import numpy as np

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402

LINE = re.compile(r"^(?P<stage>[\w.-]+): ep\s+(?P<episode>\d+) \| food\s+(?P<food>[\d.]+) .*?"
                  r"\bent (?P<entropy>[\d.]+) valid (?P<valid>[\d.]+) .*?\| kl (?P<kl>[\d.]+)")
STAGE = re.compile(r"^stage (?P<index>\d+)/(?P<count>\d+) (?P<stage>[\w.-]+):")
SIGNALS = (("food", "food (mean over the episode set's worlds)"), ("entropy", "entropy"),
           ("valid", "valid-action accuracy"), ("kl", "approx. KL of an update"))
WINDOW = 40  # episodes in the rolling mean of the table and the curves


@dataclass
class SeedLog:
    """One seed's logged episode sets, per stage in the recipe's order."""

    name: str
    stages: list[str] = field(default_factory=list)
    points: dict[str, dict[int, dict[str, float]]] = field(default_factory=dict)
    lengths: dict[str, int] = field(default_factory=dict)  # a stage's episodes (progress.json, else its last line)

    def offsets(self) -> dict[str, int]:
        """Where each stage starts on the seed's recipe-episode axis."""
        start, offsets = 0, {}
        for stage in self.stages:
            offsets[stage] = start
            start += self.lengths.get(stage, 0)
        return offsets


def _parse(log: Path, seed: SeedLog) -> None:
    """Add ``log``'s stage order and episode sets to ``seed``."""
    for line in log.read_text(errors="replace").splitlines():
        if (started := STAGE.match(line)) is not None:
            index, stage = int(started["index"]) - 1, started["stage"]
            if index >= len(seed.stages):
                seed.stages.extend([""] * (index + 1 - len(seed.stages)))
            seed.stages[index] = stage
        elif (point := LINE.match(line)) is not None:
            values = {name: float(point[name]) for name, _ in SIGNALS}
            seed.points.setdefault(point["stage"], {})[int(point["episode"])] = values


def read_seed(log: Path, run: Path | None = None, earlier: list[Path] = ()) -> SeedLog:
    """Parse ``log``; ``run`` (the seed's run folder) gives finished stages' lengths; a stage with
    no line in it takes its lines from the first of the ``earlier`` logs that has them (a stage
    copied from another run)."""
    seed = SeedLog(log.stem)
    _parse(log, seed)
    for other in earlier:
        if other.is_file():
            found = SeedLog(other.stem)
            _parse(other, found)
            for stage in seed.stages:
                if not seed.points.get(stage) and found.points.get(stage):
                    seed.points[stage] = found.points[stage]
    for stage in seed.stages:
        progress = run / stage / "progress.json" if run is not None else None
        if progress is not None and progress.is_file():
            seed.lengths[stage] = int(json.loads(progress.read_text())["episode"])
        elif seed.points.get(stage):
            seed.lengths[stage] = max(seed.points[stage])
    return seed


def rolling(episodes: list[int], values: list[float], window: int = WINDOW) -> np.ndarray:
    """The mean of the points within the last ``window`` episodes of each point."""
    e, v = np.asarray(episodes), np.asarray(values)
    return np.array([v[(e > end - window) & (e <= end)].mean() for end in e])


def stage_rows(seed: SeedLog, window: int = WINDOW) -> list[tuple[str, int, float, float]]:
    """Per logged stage: its episodes, the rolling food at its end and its deepest fall after its
    best (1 - the lowest rolling food after the best / the best), over full windows only (a mean
    of a stage's first one or two episode sets is noise, not a best)."""
    rows = []
    for stage in seed.stages:
        points = seed.points.get(stage)
        if not points:
            continue
        episodes = sorted(points)
        food = rolling(episodes, [points[e]["food"] for e in episodes], window)
        food = food[np.asarray(episodes) >= min(window, episodes[-1])]
        best = int(np.argmax(food))
        rows.append((stage, seed.lengths[stage], float(food[-1]), float(1 - food[best:].min() / food[best])))
    return rows


def plot(seeds: list[SeedLog], out: Path) -> None:
    figure, axes = plt.subplots(len(SIGNALS), 1, figsize=(11, 2.4 * len(SIGNALS)), sharex=True)
    colours = plt.get_cmap("tab10")
    for i, seed in enumerate(seeds):
        offsets, label = seed.offsets(), seed.name  # the legend names a seed once, at its first line
        for stage in seed.stages:
            points = seed.points.get(stage, {})
            episodes = sorted(points)
            if not episodes:
                continue
            x = np.asarray(episodes) + offsets[stage]
            for axis, (name, _) in zip(axes, SIGNALS):
                y = rolling(episodes, [points[e][name] for e in episodes])
                axis.plot(x, y, color=colours(i % 10), lw=1.2, label=label)
            label = None
            for axis in axes:
                axis.axvline(offsets[stage], color=colours(i % 10), lw=0.5, ls=":")
    for axis, (name, title) in zip(axes, SIGNALS):
        axis.set_ylabel(title, fontsize=8)
        axis.grid(alpha=0.3)
    axes[0].legend(fontsize=8, ncol=min(8, len(seeds)))
    first = max(seeds, key=lambda s: len(s.stages))
    for stage, start in first.offsets().items():
        axes[0].annotate(stage, (start, 1.0), xycoords=("data", "axes fraction"), fontsize=8, va="bottom")
    axes[-1].set_xlabel(f"recipe episode (stages end to end per seed; dotted: a stage's start; {WINDOW}-episode "
                        "rolling means)")
    figure.tight_layout()
    out.parent.mkdir(parents=True, exist_ok=True)
    figure.savefig(out, dpi=90)
    plt.close(figure)


@click.command()
@click.argument("run", type=click.Path(exists=True, file_okay=False, path_type=Path))
@click.option("--out", type=click.Path(dir_okay=False, path_type=Path), help="Write the figure here (PNG).")
@click.option("--stages-from", "earlier", multiple=True, type=click.Path(exists=True, file_okay=False, path_type=Path),
              help="Another recipe run folder whose seedS.log has the lines of a stage this run copied from it.")
def main(run: Path, out: Path | None, earlier: tuple[Path, ...]) -> None:
    """The seeds of the recipe run folder RUN (its seedS.log files and seedS/ folders)."""
    logs = sorted(run.glob("seed*.log"), key=lambda p: int(re.sub(r"\D", "", p.stem) or 0))
    if not logs:
        raise click.UsageError(f"{run} has no seedS.log")
    seeds = [read_seed(log, run / log.stem, [folder / log.name for folder in earlier]) for log in logs]
    click.echo(f"| seed | stage | episodes | food, last {WINDOW} episodes | deepest fall after its best |")
    click.echo("|---|---|---|---|---|")
    for seed in seeds:
        for stage, episodes, food, fall in stage_rows(seed):
            click.echo(f"| {seed.name} | {stage} | {episodes} | {food:.1f} | {fall:.0%} |")
    if out is not None:
        plot(seeds, out)
        click.echo(f"wrote {out}")


if __name__ == "__main__":
    main()
