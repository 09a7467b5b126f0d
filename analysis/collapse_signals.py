"""Which training signal moves first when a `paper` recipe seed collapses, and at which schedule event?

Reads each seed's basics -> reference -> crowd stages from their TensorBoard logs (one point per
episode set of 4 worlds), puts them on one episode axis, draws one column per seed and prints,
per seed and signal, the first episode where the signal departs by this rule:

    each signal's band is the mean +/- K standard deviations of its raw values in the BAND
    episodes (default reference episodes 100-200: every seed healthy, the hand-off settled);
    its departure is the first later episode from which its WINDOW-episode rolling mean stays
    outside the band on the bad side (food, valid-action accuracy and act-ok down; entropy,
    clip fraction, approx KL and value loss up) for HOLD logged points.

A band fixed in one healthy stretch, not one that slides with the run: a band of the previous 100
episodes follows a slow drift (seed 1's food never leaves it), and these collapses are drifts.

    .venv/bin/python analysis/collapse_signals.py models/training/recipe-paper --out docs/collapse_signals.png
"""

from __future__ import annotations

import csv
import gzip
import io
from pathlib import Path

import click
import matplotlib
import numpy as np
from PIL import Image

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402

from formic_trainer.scalars import read_scalars  # noqa: E402

STAGES = ("basics", "reference", "crowd")
# (name, TensorBoard tag, bad direction: +1 = a rise is bad, -1 = a fall is bad)
SIGNALS = (("food", "train/food_mean", -1), ("entropy", "train/entropy", +1),
           ("clip fraction", "train/clip_fraction", +1), ("approx KL", "train/approx_kl", +1),
           ("value loss", "train/value", +1), ("valid-action acc.", "train/valid_accuracy", -1),
           ("act-ok rate", "train/valid_rate", -1))
FILTER, HIGHWAYS = "train/filter_probability", "train/highway_intensity"

SIGNALS_FILE = Path(__file__).with_name("collapse_signals.csv.gz")  # extracted from the tb files
Series = tuple[np.ndarray, np.ndarray]  # episodes on the common axis, values


def tensorboard_rows(seed_dir: Path) -> list[tuple[str, int, str, float]]:
    """(stage, step, tag, value) of the signals this analysis reads, from a seed's TensorBoard files."""
    tags = {tag for _, tag, _ in SIGNALS} | {FILTER, HIGHWAYS}
    return [(stage, step, tag, value) for stage in STAGES
            for tag, points in read_scalars(seed_dir / stage).items() if tag in tags
            for step, value in points]


def write_signals(path: Path, rows: dict[int, list[tuple[str, int, str, float]]]) -> None:
    """The rows of every seed as one gzipped CSV (gzip mtime 0: the same rows give the same bytes)."""
    lines = ["seed,stage,step,tag,value"] + [f"{seed},{stage},{step},{tag},{value!r}"
                                            for seed, seed_rows in rows.items() for stage, step, tag, value in seed_rows]
    with open(path, "wb") as raw, gzip.GzipFile(fileobj=raw, mode="wb", mtime=0) as handle:
        handle.write(("\n".join(lines) + "\n").encode())


def read_signals(path: Path, seed: int) -> list[tuple[str, int, str, float]]:
    with gzip.open(path, "rt") as handle:
        return [(row["stage"], int(row["step"]), row["tag"], float(row["value"]))
                for row in csv.DictReader(handle) if int(row["seed"]) == seed]


def load_seed(rows: list[tuple[str, int, str, float]]) -> tuple[dict[str, Series], dict[str, int]]:
    """Every tag of the three stages on one episode axis (a stage continues at the episode the
    previous one ended), and the episode each stage starts at."""
    series: dict[str, tuple[list[int], list[float]]] = {}
    starts, offset = {}, 0
    for stage in STAGES:
        starts[stage] = offset
        steps = [(step, tag, value) for name, step, tag, value in rows if name == stage]
        for step, tag, value in steps:
            episodes, values = series.setdefault(tag, ([], []))
            episodes.append(offset + step)
            values.append(value)
        offset += max(step for step, _, _ in steps)
    starts["end"] = offset
    return {tag: (np.array(e), np.array(v)) for tag, (e, v) in series.items()}, starts


def schedule_events(series: dict[str, Series], starts: dict[str, int]) -> dict[str, int]:
    """Where the reference stage's filter anneal and highway fade end (their last logged point
    above zero) and where the crowd stage starts."""
    events = {}
    for name, tag in (("filter anneal end", FILTER), ("highway fade end", HIGHWAYS)):
        episodes, values = series[tag]
        ref = (episodes > starts["reference"]) & (episodes <= starts["crowd"])
        events[name] = int(episodes[ref][values[ref] > 0][-1])
    events["crowd start"] = starts["crowd"]
    return events


def windowed_mean(episodes: np.ndarray, values: np.ndarray, window: int) -> np.ndarray:
    """At each logged episode, the mean of the values logged over the last ``window`` episodes."""
    return np.array([values[(episodes > e - window) & (episodes <= e)].mean() for e in episodes])


def first_departure(episodes: np.ndarray, values: np.ndarray, direction: int, window: int,
                    band: tuple[int, int], k: float, hold: int) -> int | None:
    """The first episode after ``band`` from which the ``window``-episode mean stays more than ``k``
    standard deviations (of the raw values logged in episodes ``band[0] < e <= band[1]``) beyond
    their mean in ``direction`` (+1 above, -1 below) for ``hold`` logged points; None if never."""
    inside = (episodes > band[0]) & (episodes <= band[1])
    reference = values[inside]
    beyond = direction * (windowed_mean(episodes, values, window) - reference.mean()) > k * reference.std()
    for i in np.flatnonzero(episodes > band[1]):
        if i + hold <= len(episodes) and beyond[i:i + hold].all():
            return int(episodes[i])
    return None


def where(episode: int, starts: dict[str, int], series: dict[str, Series]) -> str:
    """An episode as its stage's own episode, with the filter probability and highway intensity then."""
    stage = [name for name in STAGES if starts[name] < episode][-1]
    at = {tag: series[tag][1][series[tag][0] == episode][0] for tag in (FILTER, HIGHWAYS)}
    return f"{stage} {episode - starts[stage]} | {at[FILTER]:.2f} | {at[HIGHWAYS]:.2f}"


@click.command()
@click.argument("recipe_dir", type=click.Path(file_okay=False, path_type=Path))
@click.option("--signals", "signals", type=click.Path(dir_okay=False, path_type=Path),
              default=SIGNALS_FILE, show_default=True,
              help="The series as a gzipped CSV: read from it when it exists, else read RECIPE_DIR's "
                   "TensorBoard files and write it (so the analysis outlives those files).")
@click.option("--seeds", default="1,2,3", show_default=True, help="Seed directories seedS to read.")
@click.option("--out", required=True, type=click.Path(dir_okay=False))
@click.option("--window", default=20, show_default=True, help="Rolling-mean window (episodes).")
@click.option("--band", default="400,500", show_default=True,
              help="Episodes FROM,TO (common axis) whose raw values set each signal's band "
                   "(400,500 = reference episodes 100-200, past the basics -> reference hand-off).")
@click.option("--k", default=2.0, show_default=True, help="Band half-width in standard deviations.")
@click.option("--hold", default=5, show_default=True, help="Logged points the mean must stay outside.")
def main(recipe_dir: Path, signals: Path, seeds: str, out: str, window: int, band: str, k: float, hold: int) -> None:
    """Draw food, entropy, clip fraction, approx KL, value loss, valid-action accuracy and act-ok
    rate per seed over basics -> reference -> crowd and print where each first departs."""
    seed_list = [int(s) for s in seeds.split(",")]
    if not signals.exists():
        write_signals(signals, {seed: tensorboard_rows(recipe_dir / f"seed{seed}") for seed in seed_list})
        click.echo(f"wrote {signals}")
    band_span = tuple(int(e) for e in band.split(","))
    fig, axes = plt.subplots(len(SIGNALS) + 1, len(seed_list), figsize=(4 * len(seed_list), 12),
                             sharex=True, squeeze=False)
    rows, missing = [], set()
    for col, seed in enumerate(seed_list):
        series, starts = load_seed(read_signals(signals, seed))
        events = schedule_events(series, starts)
        for row, (name, tag, direction) in enumerate(SIGNALS):
            ax = axes[row, col]
            if tag not in series:
                missing.add(name)
                ax.text(0.5, 0.5, "not logged by this code", ha="center", va="center", transform=ax.transAxes,
                        fontsize=8)
            else:
                episodes, values = series[tag]
                smooth = windowed_mean(episodes, values, window)
                ax.plot(episodes, values, color="0.75", linewidth=0.5)
                ax.plot(episodes, smooth, linewidth=1)
                inside = values[(episodes > band_span[0]) & (episodes <= band_span[1])]
                ax.fill_between(band_span, inside.mean() - k * inside.std(), inside.mean() + k * inside.std(),
                                color="tab:orange", alpha=0.3, linewidth=0)
                found = first_departure(episodes, values, direction, window, band_span, k, hold)
                rows.append((seed, name, found, where(found, starts, series) if found is not None else "- | - | -"))
                if found is not None:
                    ax.plot([found], [smooth[episodes == found][0]], "rv")
            if col == 0:
                ax.set_ylabel(name, fontsize=8)
        sched = axes[-1, col]
        for tag, label in ((FILTER, "filter probability"), (HIGHWAYS, "highway intensity")):
            sched.plot(*series[tag], label=label, linewidth=1)
        for ax in axes[:, col]:
            for stage in STAGES[1:]:
                ax.axvline(starts[stage], color="k", linewidth=0.8)
            ax.axvline(events["filter anneal end"], color="tab:red", linestyle="--", linewidth=0.8)
            ax.axvline(events["highway fade end"], color="tab:green", linestyle=":", linewidth=1.2)
            ax.tick_params(labelsize=7)
        axes[0, col].set_title(f"seed {seed}", fontsize=9)
        sched.set_xlabel("episode: basics | reference | crowd", fontsize=8)
    axes[-1, 0].set_ylabel("schedule", fontsize=8)
    axes[-1, 0].legend(fontsize=6)
    fig.suptitle(f"grey: each episode set; blue: {window}-episode mean; orange: band (mean +/- {k:g} sd of episodes "
                 f"{band_span[0]}-{band_span[1]}); red mark: first departure (bad direction, held {hold} points)\n"
                 "black: reference and crowd stage starts; red dashed: reference filter anneal end; green dotted: "
                 "reference highway fade end (both at the crowd start)", fontsize=7)
    fig.tight_layout(rect=(0, 0, 1, 0.97))
    buffer = io.BytesIO()
    fig.savefig(buffer, dpi=90)
    Image.open(buffer).convert("RGB").quantize(colors=64).save(out, optimize=True)  # a third of the bytes
    click.echo(f"wrote {out}")
    click.echo("| seed | signal | first departure | stage episode | filter p | highways |\n|---|---|---|---|---|---|")
    for seed in seed_list:
        for row in sorted((r for r in rows if r[0] == seed), key=lambda r: (r[2] is None, r[2] or 0)):
            click.echo(f"| {row[0]} | {row[1]} | {row[2] if row[2] is not None else '-'} | {row[3]} |")
    for name in sorted(missing):
        click.echo(f"{name}: not logged by the code that trained these runs")


if __name__ == "__main__":
    main()
