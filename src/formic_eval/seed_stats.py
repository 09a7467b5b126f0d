"""Statistics over training seeds (issue 46): robust aggregates and intervals across seeds.

The method of Agarwal et al. 2021 ("Deep RL at the edge of the statistical precipice", the
``rliable`` library), written on numpy/scipy because rliable's dependency ``arch`` does not import
with our pinned stack. A score array has shape (seeds, tasks): a task is one Fig. 5 cell, a score
one seed's mean food on the cell's scenarios, optionally normalised (e.g. divided by the paper's
value). The seeds are the unit of replication here, not the test scenarios: an interval over
seeds says how another seed of the same recipe would do.

Intervals are 95% percentile intervals of a stratified bootstrap: each replicate resamples the
seeds with replacement independently within each task, then recomputes the statistic. The
replicates come from a numpy Generator with a fixed seed (``BOOTSTRAP_SEED``), so a report is
the same every time it is built from the same scores; 2,000 replicates by default.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike
from scipy import stats

CONFIDENCE = 0.95
REPLICATES = 2000
BOOTSTRAP_SEED = 0
# the rule: a seed collapses when its mean validation food is below this share of the median seed's
COLLAPSE_RATIO = 0.75


@dataclass(frozen=True)
class Estimate:
    """A point estimate and its interval."""

    value: float
    low: float
    high: float

    def text(self, digits: int = 0, signed: bool = False) -> str:
        """``234 [154, 274]``; ``signed`` writes ``+20 [-2, +41]``."""
        form = f"{{:{'+' if signed else ''}.{digits}f}}"
        return f"{form.format(self.value)} [{form.format(self.low)}, {form.format(self.high)}]"


def iqm(scores: ArrayLike) -> float:
    """The interquartile mean, as rliable defines it: the mean of the middle 50% of all scores
    pooled (every seed and task), ``scipy.stats.trim_mean`` cutting 25% at each end (of n
    scores, floor(n/4) from each end: with fewer than 4 it is the plain mean)."""
    return float(stats.trim_mean(np.ravel(scores), 0.25))


def _scores(scores: ArrayLike) -> np.ndarray:
    array = np.asarray(scores, dtype=np.float64)
    if array.ndim != 2 or 0 in array.shape:
        raise ValueError(f"scores need shape (seeds, tasks) with at least one of each, got {array.shape}")
    return array


def stratified_resamples(scores: ArrayLike, replicates: int = REPLICATES, seed: int = BOOTSTRAP_SEED) -> np.ndarray:
    """``replicates`` bootstrap copies of ``scores``, shape (replicates, seeds, tasks): each
    task's column is its own seeds drawn with replacement, independently of the other tasks."""
    array = _scores(scores)
    seeds, tasks = array.shape
    rows = np.random.default_rng(seed).integers(0, seeds, size=(replicates, seeds, tasks))
    return array[rows, np.arange(tasks)]


def _interval(values: np.ndarray, confidence: float) -> tuple[np.ndarray, np.ndarray]:
    """The percentile interval of bootstrap statistics along their first axis."""
    tail = 50 * (1 - confidence)
    low, high = np.percentile(values, [tail, 100 - tail], axis=0)
    return low, high


@dataclass(frozen=True)
class OverSeeds:
    """Mean and IQM over seeds, per task and over all tasks, each with its bootstrap interval."""

    task_means: tuple[Estimate, ...]
    task_iqms: tuple[Estimate, ...]
    mean: Estimate
    iqm: Estimate


def over_seeds(scores: ArrayLike, replicates: int = REPLICATES, seed: int = BOOTSTRAP_SEED,
               confidence: float = CONFIDENCE) -> OverSeeds:
    """The mean and the IQM of a (seeds, tasks) score array, per task (over its seeds) and
    aggregate (over every seed and task), with 95% stratified bootstrap intervals (2,000
    replicates from a fixed generator seed by default). One set of resamples serves every
    statistic: a task's column of a stratified resample is a bootstrap resample of its seeds."""
    array = _scores(scores)
    draws = stratified_resamples(array, replicates, seed)
    flat = draws.reshape(replicates, -1)

    def estimates(points: np.ndarray, boot: np.ndarray) -> tuple[Estimate, ...]:
        low, high = _interval(boot, confidence)
        return tuple(Estimate(float(p), float(lo), float(hi)) for p, lo, hi in
                     zip(np.atleast_1d(points), np.atleast_1d(low), np.atleast_1d(high)))

    return OverSeeds(
        task_means=estimates(array.mean(axis=0), draws.mean(axis=1)),
        task_iqms=estimates(stats.trim_mean(array, 0.25, axis=0), stats.trim_mean(draws, 0.25, axis=1)),
        mean=estimates(array.mean(), flat.mean(axis=1))[0],
        iqm=estimates(iqm(array), stats.trim_mean(flat, 0.25, axis=1))[0],
    )


def t_interval(values: ArrayLike, confidence: float = CONFIDENCE) -> Estimate:
    """The mean of ``values`` and its Student t interval (infinite for a single value)."""
    x = np.ravel(np.asarray(values, dtype=np.float64))
    if x.size == 0:
        raise ValueError("no values")
    mean = float(x.mean())
    if x.size == 1:
        return Estimate(mean, float("-inf"), float("inf"))
    half = float(stats.t.ppf(0.5 + confidence / 2, x.size - 1) * x.std(ddof=1) / np.sqrt(x.size))
    return Estimate(mean, mean - half, mean + half)


def bootstrap_interval(values: ArrayLike, statistic: Callable[[np.ndarray], np.ndarray] = np.mean,
                       replicates: int = REPLICATES, seed: int = BOOTSTRAP_SEED,
                       confidence: float = CONFIDENCE) -> Estimate:
    """``statistic`` of ``values`` (one per seed) and its percentile bootstrap interval
    (``statistic`` reduces along ``axis=1`` of the resamples)."""
    x = np.ravel(np.asarray(values, dtype=np.float64))
    draws = stratified_resamples(x[:, None], replicates, seed)[:, :, 0]
    low, high = _interval(statistic(draws, axis=1), confidence)
    return Estimate(float(statistic(x[None, :], axis=1)[0]), float(low), float(high))


@dataclass(frozen=True)
class SeedComparison:
    """Over seeds, each seed's paired mean difference with a baseline on one cell's scenarios:
    their mean, its t interval (which the verdict reads) and its bootstrap interval."""

    seeds: int
    t: Estimate
    bootstrap: Estimate

    @property
    def verdict(self) -> str:
        """``ahead`` when the t interval over seeds lies above zero, ``behind`` below, else ``level``."""
        return "ahead" if self.t.low > 0 else "behind" if self.t.high < 0 else "level"


def compare_over_seeds(differences: Sequence[float], replicates: int = REPLICATES, seed: int = BOOTSTRAP_SEED,
                       confidence: float = CONFIDENCE) -> SeedComparison:
    """``differences``: each seed's paired mean difference (ours minus the baseline's food,
    averaged over the cell's scenarios). The t interval over seeds judges the verdict: with few
    seeds the bootstrap interval is too narrow (3 seeds have only 10 distinct resample means)."""
    return SeedComparison(len(differences), t_interval(differences, confidence),
                          bootstrap_interval(differences, np.mean, replicates, seed, confidence))


def collapsed(foods: Sequence[float], ratio: float = COLLAPSE_RATIO) -> np.ndarray:
    """Which seeds collapsed: mean validation food below ``ratio`` (0.75) x the median seed's."""
    x = np.asarray(foods, dtype=np.float64)
    if x.size == 0:
        raise ValueError("no seeds")
    return x < ratio * np.median(x)
