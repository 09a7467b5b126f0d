"""Paired comparisons: every "A beats B" and "X% less" is a mean of per-scenario differences.

Two algorithms run on the same stored scenarios face the same layouts and the same starts, so
the difference of their food on each scenario removes most of the layout-to-layout spread
(a 128-agent cell's std is ~100 food, its paired differences' a fraction of that). The interval
is Student's t at 95% over the pairs. A wipeout episode is paired with the infinite-resource
episode of the same layout: both settings draw their layouts from the same seeds (the layout
seed does not depend on the wipeouts, ``matrix.layout_seed``), so the pair differs only by the
wipeouts.

"X% less" divides the mean difference and its interval by the baseline's mean food on the same
pairs (the baseline mean is treated as fixed; its own spread is not propagated).
"""

from __future__ import annotations

from collections.abc import Callable, Iterable
from dataclasses import dataclass

import numpy as np
from scipy import stats

# what identifies one scenario of one setting across algorithms and evaluation folders
SCENARIO_KEY = ("size", "agents", "obstacles", "env", "steps", "scenario_digest")
# what identifies one layout across environments that share it (infinite and wipeout)
LAYOUT_KEY = ("size", "agents", "obstacles", "steps", "seed")


@dataclass(frozen=True)
class PairedDifference:
    """Mean of ``a - b`` over ``n`` paired scenarios, its 95% interval, and ``b``'s mean."""

    n: int
    mean: float
    low: float
    high: float
    base_mean: float

    @property
    def significant(self) -> bool:
        """The interval excludes zero."""
        return self.low > 0 or self.high < 0

    def percent(self) -> tuple[float, float, float]:
        """The difference as a percentage of ``b``'s mean food: (mean, low, high)."""
        scale = 100.0 / self.base_mean if self.base_mean else float("nan")
        return self.mean * scale, self.low * scale, self.high * scale

    def food_text(self) -> str:
        """As the README's tables print it: ``+12 [+3, +21] (n=20)``."""
        return f"{self.mean:+.0f} [{self.low:+.0f}, {self.high:+.0f}] (n={self.n})"


def paired_difference(a: Iterable[float], b: Iterable[float], confidence: float = 0.95) -> PairedDifference:
    """``a[i] - b[i]`` summarised; ``a`` and ``b`` are aligned pairs (at least one)."""
    a, b = np.asarray(list(a), dtype=np.float64), np.asarray(list(b), dtype=np.float64)
    if a.shape != b.shape or a.size == 0:
        raise ValueError(f"need equally many pairs, at least one (got {a.size} and {b.size})")
    diff = a - b
    mean = float(diff.mean())
    if diff.size == 1:
        return PairedDifference(1, mean, float("-inf"), float("inf"), float(b.mean()))
    half = float(stats.t.ppf(0.5 + confidence / 2, diff.size - 1) * diff.std(ddof=1) / np.sqrt(diff.size))
    return PairedDifference(int(diff.size), mean, mean - half, mean + half, float(b.mean()))


def pair_records(a: Iterable[dict], b: Iterable[dict],
                 key: Callable[[dict], tuple] = lambda r: tuple(r[k] for k in SCENARIO_KEY)
                 ) -> dict[tuple, list[tuple[dict, dict]]]:
    """Episodes of ``a`` and ``b`` on the same scenario, grouped by setting (the key without
    its last field). A scenario that only one side ran is left out; one that a side ran twice
    is an error (two models or variants mixed in one list)."""
    def index(records: Iterable[dict], side: str) -> dict[tuple, dict]:
        found: dict[tuple, dict] = {}
        for record in records:
            k = key(record)
            if k in found:
                raise ValueError(f"{side}: two episodes on one scenario {k}")
            found[k] = record
        return found

    left, right = index(a, "first"), index(b, "second")
    groups: dict[tuple, list[tuple[dict, dict]]] = {}
    for k in sorted(left.keys() & right.keys(), key=str):
        groups.setdefault(k[:-1], []).append((left[k], right[k]))
    return groups


def compare(a: Iterable[dict], b: Iterable[dict], key: Callable[[dict], tuple] | None = None
            ) -> dict[tuple, PairedDifference]:
    """Per setting: the paired difference of food, ``a`` minus ``b``."""
    groups = pair_records(a, b) if key is None else pair_records(a, b, key)
    return {setting: paired_difference([x["food"] for x, _ in pairs], [y["food"] for _, y in pairs])
            for setting, pairs in groups.items()}


def layout_key(record: dict) -> tuple:
    """Pairs a wipeout episode with the infinite-resource episode of the same layout."""
    return tuple(record[k] for k in LAYOUT_KEY)
