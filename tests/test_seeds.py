"""Several seeds of one recipe: the validation choice among them and the test table (issue 25)."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

from formic_eval.paper import paper_food
from formic_eval.seeds import SeedValidation, mean_over_seeds, seed_means, shipped_seed, spread

ROOT = Path(__file__).resolve().parents[1]
SETTING = dict(size=128, agents=16, obstacles=0.0, env="infinite", steps=1024)


def record(algorithm: str, digest: str, food: float, **setting) -> dict:
    fields = SETTING | setting
    return {"key": f"{algorithm}|{digest}|{fields['agents']}", "algorithm": algorithm, "variant": "", "model": "",
            "seed": 7, "scenario": digest, "scenario_digest": digest, "food": food, **fields}


def write_episodes(folder: Path, records: list[dict]) -> Path:
    folder.mkdir(parents=True)
    (folder / "episodes.jsonl").write_text("".join(json.dumps(r) + "\n" for r in records))
    return folder


def write_selection(run: Path, chosen: str, food_mean: float, by_team: dict[int, float]) -> Path:
    run.mkdir(parents=True)
    score = {"food_mean": food_mean, "food_by_team": {str(n): f for n, f in by_team.items()}}
    (run / "selection.json").write_text(json.dumps({"chosen": chosen, "candidates": {chosen: score}}))
    return run


def test_the_seed_with_the_best_validation_food_ships_and_a_tie_keeps_the_first(tmp_path):
    a = SeedValidation.load(write_selection(tmp_path / "seed1", "novalid.mean", 200.0, {16: 100.0, 32: 300.0}))
    b = SeedValidation.load(write_selection(tmp_path / "seed2", "novalid128.mean", 250.0, {16: 150.0, 32: 350.0}))
    tie = SeedValidation("seed3", "novalid.mean", 250.0, {})
    assert (a.name, a.chosen, a.food_by_team) == ("seed1", "novalid.mean", {16: 100.0, 32: 300.0})
    assert shipped_seed([a, b]) is b and shipped_seed([a, b, tie]) is b
    with pytest.raises(ValueError, match="no seeds"):
        shipped_seed([])


def test_a_broken_selection_file_is_a_clear_error(tmp_path):
    (tmp_path / "seed1").mkdir()
    (tmp_path / "seed1" / "selection.json").write_text('{"chosen": "x"')
    with pytest.raises(ValueError, match="selection.json: no readable validation choice"):
        SeedValidation.load(tmp_path / "seed1")
    with pytest.raises(ValueError, match="no readable validation choice"):
        SeedValidation.load(tmp_path / "missing")


def test_the_mean_over_seeds_pairs_only_scenarios_every_seed_played():
    seeds = {"seed1": [record("formic", "a", 100), record("formic", "b", 120)],
             "seed2": [record("formic", "a", 140), record("formic", "b", 160), record("formic", "c", 999)]}
    pooled = mean_over_seeds(seeds)
    assert [(r["scenario_digest"], r["food"], r["seeds"]) for r in pooled] == [("a", 120.0, 2), ("b", 140.0, 2)]
    assert seed_means(seeds) == {(128, 16, 0.0, "infinite", 1024): {"seed1": 110.0, "seed2": 433.0}}
    assert spread([110.0, 150.0]) == (130.0, pytest.approx(28.2843, abs=1e-4)) and spread([5.0]) == (5.0, 0.0)
    with pytest.raises(ValueError, match="seed1: two episodes on one scenario"):
        mean_over_seeds({"seed1": [record("formic", "a", 1), record("formic", "a", 2)]})


def test_the_table_reports_each_seed_their_spread_the_paper_and_paired_differences(tmp_path):
    runs = [write_selection(tmp_path / "runs" / "seed1", "novalid.mean", 200.0, {16: 110.0}),
            write_selection(tmp_path / "runs" / "seed2", "novalid128.mean", 250.0, {16: 150.0})]
    evals = [write_episodes(tmp_path / "evals" / "seed1", [record("formic", "a", 100), record("formic", "b", 120)]),
             write_episodes(tmp_path / "evals" / "seed2", [record("formic", "a", 140), record("formic", "b", 160)])]
    baselines = write_episodes(tmp_path / "baselines", [
        record("csaf11", "a", 90), record("csaf11", "b", 100), record("cardinality", "a", 130),
        record("cardinality", "b", 130), record("csaf11", "a", 5, agents=32)])  # a cell no seed played
    done = subprocess.run([sys.executable, str(ROOT / "scripts" / "seeds_table.py"), "--runs", *map(str, runs),
                           "--evals", *map(str, evals), "--baselines", str(baselines)],
                          capture_output=True, text=True, timeout=60)
    assert done.returncode == 0, done.stderr
    lines = done.stdout.splitlines()
    assert "| seed1 | novalid.mean | 110.0 | 200.0 |" in lines and "| seed2 | novalid128.mean | 150.0 | 250.0 |" in lines
    assert "Mean over seeds 225.0 ± 35.4. Chosen to ship: **seed2** (novalid128.mean)" in done.stdout
    published = paper_food({"algorithm": "formic", "variant": "", **SETTING})
    # pooled per scenario: a 120, b 140; C-SAF-11 a 90, b 100: differences 30 and 40, t(1) interval
    # 35 +- 12.706 * 5; Cardinality-MR 130 both: -10 and +10. Alone: seed1 is behind Cardinality-MR.
    row = (f"| infinite, 0% obstacles | 16 | 110 | 150 | 130 ± 28 | {published:.0f} | {130 / published:.2f} | "
           "+35 [-29, +99] (n=2) | 2 of 2 | +0 [-127, +127] (n=2) | 1 of 2 |")
    assert row in lines, done.stdout
    assert sum(line.startswith("| ") and " | 32 | " in line for line in lines) == 0  # no seed played 32 agents


def test_evals_must_match_the_runs_one_for_one(tmp_path):
    run = write_selection(tmp_path / "seed1", "novalid.mean", 1.0, {16: 1.0})
    done = subprocess.run([sys.executable, str(ROOT / "scripts" / "seeds_table.py"), "--runs", str(run),
                           "--evals", str(tmp_path / "a"), str(tmp_path / "b")], capture_output=True, text=True,
                          timeout=60)
    assert done.returncode == 2 and "--evals names 2 folders for 1 runs" in done.stderr


def test_readme_seeds_block_is_current():
    """The README's seeds block is what scripts/seeds_table.py builds from the committed runs and
    evaluation folders (its defaults: every finished recipe-paper seed)."""
    script = ROOT / "scripts" / "seeds_table.py"
    done = subprocess.run([sys.executable, str(script), "--check", str(ROOT / "README.md")],
                          capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr


def test_every_finished_seed_has_its_current_card_in_seeds_md():
    """models/training/recipe-paper/SEEDS.md holds scripts/model_card.py's block for every seed
    that has finished (its selection.json), each as the run folder now says."""
    import re

    page = ROOT / "models" / "training" / "recipe-paper" / "SEEDS.md"
    carded = re.findall(r"<!-- card:begin \(scripts/model_card.py (\S+)\) -->", page.read_text())
    finished = sorted(p.parent.relative_to(ROOT).as_posix()
                      for p in (ROOT / "models" / "training" / "recipe-paper").glob("seed*/selection.json"))
    assert sorted(carded) == finished
    for run in carded:
        done = subprocess.run([sys.executable, str(ROOT / "scripts" / "model_card.py"), run, "--check", str(page)],
                              capture_output=True, text=True, timeout=120, cwd=ROOT)
        assert done.returncode == 0, done.stderr


def test_the_default_model_is_the_seed_validation_chooses_and_its_card_is_current():
    """models/formic_recipe.pt, the default `formic` policy, is byte for byte the model.pt of the
    finished seed with the highest validation food, and models/formic_recipe.md holds that run's
    current card block."""
    from formic_runtime.registry import DEFAULT_MODEL

    runs = ROOT / "models" / "training" / "recipe-paper"
    finished = sorted(p.parent for p in runs.glob("seed*/selection.json"))
    chosen = shipped_seed([SeedValidation.load(run) for run in finished])
    shipped = ROOT / "models" / "formic_recipe.pt"
    assert DEFAULT_MODEL == shipped
    assert shipped.read_bytes() == (runs / chosen.name / "model.pt").read_bytes(), chosen.name
    card = ROOT / "models" / "formic_recipe.md"
    run = (runs / chosen.name).relative_to(ROOT).as_posix()
    done = subprocess.run([sys.executable, str(ROOT / "scripts" / "model_card.py"), run, "--model",
                           "models/formic_recipe.pt", "--check", str(card)],
                          capture_output=True, text=True, timeout=120, cwd=ROOT)
    assert done.returncode == 0, done.stderr
