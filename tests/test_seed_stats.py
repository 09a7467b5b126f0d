"""Statistics over seeds (issue 46): IQM, stratified bootstrap, t interval over seeds, collapse rule."""

from __future__ import annotations

import numpy as np
import pytest

from formic_eval.seed_stats import (Estimate, bootstrap_interval, collapsed, compare_over_seeds, iqm, over_seeds,
                                    stratified_resamples, t_interval)

# 4 seeds x 2 tasks
SCORES = [[1.0, 10.0], [2.0, 20.0], [3.0, 30.0], [4.0, 40.0]]


def test_the_iqm_is_the_mean_of_the_middle_half_of_every_seed_and_task_pooled():
    # pooled and sorted: 1 2 3 4 10 20 30 40; a quarter of 8 is 2 cut at each end: (3 + 4 + 10 + 20) / 4
    assert iqm(SCORES) == 9.25
    summary = over_seeds(SCORES)
    assert summary.iqm.value == 9.25 and summary.mean.value == 110 / 8
    # per task, over its 4 seeds: one cut at each end, (2 + 3) / 2 and (20 + 30) / 2
    assert [e.value for e in summary.task_iqms] == [2.5, 25.0]
    assert [e.value for e in summary.task_means] == [2.5, 25.0]
    assert iqm([[1.0], [2.0], [9.0]]) == 4.0  # fewer than 4 scores: nothing is cut, the plain mean


def test_the_t_interval_over_seeds_and_its_verdict():
    # [1, 2, 3, 4]: mean 2.5, sample std sqrt(5/3) = 1.29099, standard error 0.645497;
    # t(0.975, 3 dof) = 3.182446, half width 2.054260: [0.445740, 4.554260], above zero
    ahead = compare_over_seeds([1.0, 2.0, 3.0, 4.0])
    assert ahead.seeds == 4 and ahead.t.value == 2.5
    assert ahead.t.low == pytest.approx(0.4457397, abs=1e-6) and ahead.t.high == pytest.approx(4.5542603, abs=1e-6)
    assert ahead.verdict == "ahead"
    # [-3, -2, -1, -2]: mean -2, std sqrt(2/3), error 0.408248, half 1.299228: [-3.299228, -0.700772]
    behind = compare_over_seeds([-3.0, -2.0, -1.0, -2.0])
    assert behind.t.low == pytest.approx(-3.299228, abs=1e-6) and behind.t.high == pytest.approx(-0.700772, abs=1e-6)
    assert behind.verdict == "behind"
    # [15, 55]: mean 35, std 28.2843, error 20; t(0.975, 1 dof) = 12.706205: 35 -+ 254.1241
    level = compare_over_seeds([15.0, 55.0])
    assert level.t.low == pytest.approx(-219.12409, abs=1e-4) and level.t.high == pytest.approx(289.12409, abs=1e-4)
    assert level.verdict == "level"
    one = t_interval([7.0])
    assert one == Estimate(7.0, float("-inf"), float("inf")) and compare_over_seeds([7.0]).verdict == "level"
    with pytest.raises(ValueError, match="no values"):
        t_interval([])


def test_identical_seeds_give_zero_width_intervals():
    summary = over_seeds([[2.0, 5.0]] * 4)
    assert summary.task_means == (Estimate(2.0, 2.0, 2.0), Estimate(5.0, 5.0, 5.0))
    assert summary.task_iqms == summary.task_means
    assert summary.mean == Estimate(3.5, 3.5, 3.5) and summary.iqm == Estimate(3.5, 3.5, 3.5)
    assert compare_over_seeds([4.0, 4.0, 4.0]).bootstrap == Estimate(4.0, 4.0, 4.0)


def test_two_seeds_bootstrap_to_their_extremes():
    # resampling seeds {0, 1}: the mean is 0, 0.5 or 1 with chances 1/4, 1/2, 1/4, so of 2,000
    # replicates more than 2.5% are 0 and more than 2.5% are 1: the interval is [0, 1] exactly
    assert bootstrap_interval([0.0, 1.0]) == Estimate(0.5, 0.0, 1.0)
    assert compare_over_seeds([15.0, 55.0]).bootstrap == Estimate(35.0, 15.0, 55.0)


def test_resamples_draw_each_tasks_seeds_independently_and_reproducibly():
    draws = stratified_resamples([[0.0, 100.0], [1.0, 101.0]], replicates=500)
    assert draws.shape == (500, 2, 2)
    assert set(np.unique(draws[:, :, 0])) == {0.0, 1.0} and set(np.unique(draws[:, :, 1])) == {100.0, 101.0}
    assert (draws[:, :, 0] != draws[:, :, 1] - 100).any()  # the tasks are not resampled with the same seeds
    assert np.array_equal(draws, stratified_resamples([[0.0, 100.0], [1.0, 101.0]], replicates=500))
    assert not np.array_equal(draws, stratified_resamples([[0.0, 100.0], [1.0, 101.0]], replicates=500, seed=1))
    with pytest.raises(ValueError, match=r"shape \(seeds, tasks\)"):
        over_seeds([1.0, 2.0])


def test_intervals_hold_the_estimate_and_shrink_with_more_seeds():
    scores = np.random.default_rng(5).normal(1.0, 0.3, size=(4, 6))
    # the same spread of seeds, 16 times as many: the estimates stay, the intervals narrow ~4x
    few, many = over_seeds(scores), over_seeds(np.tile(scores, (16, 1)))
    for summary in (few, many):
        for e in (summary.mean, summary.iqm, *summary.task_means, *summary.task_iqms):
            assert e.low <= e.value <= e.high
    width = lambda e: e.high - e.low  # noqa: E731
    assert many.mean.value == pytest.approx(few.mean.value) and width(many.mean) < width(few.mean) / 2
    assert width(many.iqm) < width(few.iqm) / 2
    assert all(width(m) < width(f) / 2 for m, f in zip(many.task_means, few.task_means))
    assert all(width(m) < width(f) for m, f in zip(many.task_iqms, few.task_iqms))


def test_a_seed_collapses_below_three_quarters_of_the_median_seed():
    # median 92.5, threshold 69.375: only 60 is below
    assert collapsed([100.0, 60.0, 90.0, 95.0]).tolist() == [False, True, False, False]
    assert collapsed([4.0, 3.0, 4.0]).tolist() == [False, False, False]  # exactly 0.75 x the median is kept
    with pytest.raises(ValueError, match="no seeds"):
        collapsed([])


def test_estimates_print_as_the_tables_do():
    assert Estimate(234.4, 154.0, 274.2).text() == "234 [154, 274]"
    assert Estimate(20.0, -2.4, 41.0).text(signed=True) == "+20 [-2, +41]"
    assert Estimate(1.0, 0.891, 1.114).text(2) == "1.00 [0.89, 1.11]"
