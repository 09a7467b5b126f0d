"""scripts/stage_handoff.py: each recipe run's basics-to-reference hand-off, from its TensorBoard logs."""

from __future__ import annotations

from click.testing import CliRunner
from torch.utils.tensorboard import SummaryWriter

from scripts.stage_handoff import main


def write_stage(directory, scalars: dict[str, list[tuple[int, float]]]) -> None:
    with SummaryWriter(str(directory / "tb")) as writer:
        for tag, points in scalars.items():
            for step, value in points:
                writer.add_scalar(tag, value, step)


def test_runs_are_listed_by_their_last_basics_valid_share_with_the_reference_stage_food(tmp_path):
    steady, fallen, young = tmp_path / "steady", tmp_path / "fallen", tmp_path / "young"
    write_stage(steady / "basics", {"train/valid_rate": [(4, 0.5), (8, 0.9)],
                                    "train/food_mean": [(4, 20.0), (8, 60.0)]})
    write_stage(steady / "reference", {"train/food_mean": [(4, 100.0), (40, 70.0), (44, 120.0), (48, 130.0)]})
    write_stage(fallen / "basics", {"train/valid_rate": [(8, 0.7)], "train/food_mean": [(8, 45.0)]})
    write_stage(fallen / "reference", {"train/food_mean": [(4, 60.0), (16, 12.0), (44, 10.0)]})
    early = tmp_path / "early"  # still in its reference stage's first 40 episodes
    write_stage(early / "basics", {"train/valid_rate": [(8, 0.8)], "train/food_mean": [(8, 50.0)]})
    write_stage(early / "reference", {"train/food_mean": [(4, 90.0), (8, 80.0)]})
    write_stage(young / "basics", {"train/valid_rate": [(4, 0.6)], "train/food_mean": [(4, 30.0)]})
    (tmp_path / "steady.log").write_text("a run's log, not a run\n")
    runs = [str(tmp_path / name) for name in ("steady", "steady.log", "fallen", "early", "young")]
    result = CliRunner().invoke(main, runs)
    assert result.exit_code == 0, result.output
    lines = result.output.splitlines()
    assert lines[2:5] == [f"| {fallen} | 0.70 | 45.0 | 60.0 | 12.0 | 10.0 | 44 |",
                          f"| {early} | 0.80 | 50.0 | 90.0 | 80.0 | – | 8 |",
                          f"| {steady} | 0.90 | 60.0 | 100.0 | 70.0 | 125.0 | 48 |"]
    assert lines[-1] == f"skipped (no basics and reference stages logged): {young}"
