"""analysis/learning_curves.py: stages drawn one after the other, cut where a model stopped using them."""

from __future__ import annotations

import pytest
from click.testing import CliRunner
from torch.utils.tensorboard import SummaryWriter

from analysis.learning_curves import FOOD_MEAN, main, stages


def write_run(directory, food: dict[str, list[tuple[int, float]]]) -> None:
    with SummaryWriter(str(directory / "tb")) as writer:
        for tag, points in food.items():
            for step, value in points:
                writer.add_scalar(tag, value, step)


@pytest.fixture
def runs(tmp_path):
    write_run(tmp_path / "stage_a", {"train/food_env0": [(4, 1.0), (8, 2.0), (12, 3.0)],
                                     "train/food_env1": [(4, 5.0), (8, 6.0), (12, 7.0)]})
    write_run(tmp_path / "stage_b", {"train/food_env0": [(4, 10.0), (8, 20.0)], "train/entropy": [(6, 0.5)]})
    return tmp_path / "stage_a", tmp_path / "stage_b"


def test_a_stage_cut_by_until_ends_there_and_the_next_starts_at_its_last_drawn_episode(runs):
    (a, offset_a, series_a), (b, offset_b, series_b) = stages(runs, {"stage_a": 8})
    assert (a, offset_a, b, offset_b) == ("stage_a", 0, "stage_b", 8)
    assert series_a["train/food_env0"] == [(4, 1.0), (8, 2.0)]
    assert series_b["train/food_env0"] == [(4, 10.0), (8, 20.0)] and series_b["train/entropy"] == [(6, 0.5)]
    assert [offset for _, offset, _ in stages(runs, {})] == [0, 12]


def test_overlay_starts_every_run_at_zero_with_the_food_mean_of_the_worlds_logged_together(runs):
    (_, offset_a, series_a), (_, offset_b, _) = stages(runs, {}, overlay=True)
    assert offset_a == offset_b == 0
    assert series_a[FOOD_MEAN] == [(4, 3.0), (8, 4.0), (12, 5.0)]


def test_the_command_draws_a_png_and_rejects_a_malformed_until(runs, tmp_path):
    out = tmp_path / "curves.png"
    result = CliRunner().invoke(main, [*map(str, runs), "--until", "stage_a=8", "--out", str(out)])
    assert result.exit_code == 0, result.output
    assert out.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    bad = CliRunner().invoke(main, [*map(str, runs), "--until", "stage_a", "--out", str(out)])
    assert bad.exit_code != 0 and "expected RUN=EPISODE" in bad.output
