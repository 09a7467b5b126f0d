"""scripts/ablation_table.py: the paper's Table I from evaluation episodes."""

from __future__ import annotations

import json
import sys

import pytest

from scripts.ablation_table import main, row_food


def episode(agents: int, food: float, model: str = "m1", variant: str = "", **changes) -> dict:
    return {"algorithm": "formic", "variant": variant, "model": model, "size": 128, "steps": 1024,
            "env": "infinite", "obstacles": 0.0, "agents": agents, "food": food} | changes


def write(directory, episodes: list[dict]) -> None:
    """A plain episode log, each record under its own key as the evaluation logs them."""
    directory.mkdir()
    (directory / "episodes.jsonl").write_text("".join(json.dumps({"key": str(i)} | e) + "\n"
                                                      for i, e in enumerate(episodes)))


def full_set(model: str = "m1", variant: str = "", scale: float = 1.0) -> list[dict]:
    return [episode(n, scale * food, model, variant) for n in (16, 32, 64, 128) for food in (n, 3 * n)]


def test_rows_take_only_the_papers_protocol_of_one_model_and_variant(tmp_path):
    write(tmp_path / "a", full_set() + full_set(variant="no-pheromones", scale=0.5) + [
        episode(16, 999.0, steps=512), episode(16, 999.0, env="wipeout"), episode(16, 999.0, algorithm="csaf11")])
    food, model = row_food(tmp_path / "a", "")
    assert model == "m1" and food == {16: [16.0, 48.0], 32: [32.0, 96.0], 64: [64.0, 192.0], 128: [128.0, 384.0]}
    food, _ = row_food(tmp_path / "a", "no-pheromones")
    assert food[16] == [8.0, 24.0]


def test_two_models_or_a_missing_team_size_are_refused(tmp_path):
    write(tmp_path / "two", full_set("m1") + full_set("m2"))
    with pytest.raises(SystemExit, match="2 models"):
        row_food(tmp_path / "two", "")
    write(tmp_path / "short", [e for e in full_set() if e["agents"] != 64])
    with pytest.raises(SystemExit, match=r"\[64\]"):
        row_food(tmp_path / "short", "")


def test_the_table_sets_each_row_beside_the_first_and_the_papers(tmp_path, monkeypatch, capsys):
    write(tmp_path / "full", full_set() + full_set(variant="no-pheromones", scale=0.5))
    monkeypatch.setattr(sys, "argv", ["ablation_table", f"full ForMIC={tmp_path / 'full'}",
                                      f"tested without pheromones={tmp_path / 'full'}:no-pheromones"])
    main()
    rows = [line for line in capsys.readouterr().out.splitlines() if line.startswith("| full") or line.startswith("| tested")]
    assert rows[0].startswith("| full ForMIC | `m1` | 32.0 ± 16.0 | 64.0 ± 32.0 | 128.0 ± 64.0 | 256.0 ± 128.0 | 1.00 |")
    assert rows[0].endswith("| 249 | 404 | 634 | 862 | 1.00 |")
    assert "| 0.50 | 147 | 267 | 470 | 722 | 0.71 |" in rows[1]
