"""Several seeds of one recipe: the validation choice among them and the test table (issue 25)."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

from formic_eval.paper import paper_food
from formic_eval.seeds import SeedValidation, mean_over_seeds, seed_means, shipped_seed, spread, study
from formic_eval.seeds_report import collapse_line, target_lines

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


def test_the_table_reports_each_seed_the_statistics_over_seeds_and_the_targets(tmp_path):
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
    # seeds' means 110 and 150: mean and IQM 130, two seeds bootstrap to [110, 150]. Each seed's
    # paired difference with C-SAF-11 (a 90, b 100): 15 and 55, mean 35, t(1) interval 35 -+ 12.706 * 20;
    # bootstrap [15, 55]. With Cardinality-MR (130 on both): -20 and +20, 0 -+ 254.
    row = (f"| infinite, 0% obstacles | 16 | 110 | 150 | 130 [110, 150] | 130 [110, 150] | {published:.0f} | "
           f"{130 / published:.2f} | +35 [-219, +289] level | +35 [+15, +55] | "
           "+0 [-254, +254] level | +0 [-20, +20] |")
    assert row in lines, done.stdout
    assert sum(line.startswith("| ") and " | 32 | " in line for line in lines) == 0  # no seed played 32 agents
    ratios = f"{(110 / published + 150 / published) / 2:.2f}"
    assert (f"ForMIC / the paper over the 1 published cells every seed played (each seed's mean food in a cell "
            f"divided by the paper's): mean {ratios} [{110 / published:.2f}, {150 / published:.2f}]") in done.stdout
    # validation 200 and 250, median 225: nobody below 168.75
    assert "Collapse rate: 0 of 2 seeds (0%) below 0.75 x the median seed's mean validation food (225.0)." in lines
    assert "- No seed collapses (each ≥ 0.75 x the median seed's mean validation food): met: the lowest seed, " \
           "seed1, is at 0.89 x the median." in lines
    assert (f"- Mean over seeds ≥ 0.9 x the paper's ForMIC in each published Fig. 5 cell: missed in 1 of 1 published "
            f"cells: infinite, 0% obstacles, 16 agents ({130 / published:.2f} x); the lowest is "
            f"{0.9 - 130 / published:.2f} short (only 1 of the 16 published cells evaluated).") in lines
    assert ("- Ahead of C-SAF-11 in ≥ 20 of 24 cells by the t interval over seeds: missed: ahead in 0, level in 1, "
            "behind in 0 of 1 cells, 20 short (only 1 of the 24 cells evaluated).") in lines

    # the same statistics from `formic eval --report --seed-eval`, the collapse rule on test food
    from click.testing import CliRunner

    from formic_cli.main import cli

    args = ["eval", "--out", str(baselines), "--report", "--seed-eval", str(evals[0]), "--seed-eval", str(evals[1])]
    result = CliRunner().invoke(cli, args)
    assert result.exit_code == 0, result.output
    assert row in result.output.splitlines()
    assert ("Collapse rate: 0 of 2 seeds (0%) below 0.75 x the median seed's mean test food over the 1 Fig. 5 "
            "cells every seed played (no validation given) (130.0).") in result.output
    assert not (baselines / "results.md").exists()  # the baselines' folder is read, not rebuilt
    study = json.loads(CliRunner().invoke(cli, [*args, "--json"]).output)["study"]
    assert study["cells"][0]["versus"]["csaf11"]["t"]["value"] == 35.0 and study["names"] == ["seed1", "seed2"]
    refused = CliRunner().invoke(cli, ["eval", "--out", str(baselines), "--seed-eval", str(evals[0])])
    assert refused.exit_code == 2 and "--seed-eval goes with --report" in refused.output


def test_the_targets_name_the_collapsed_seed_and_the_cells_ahead():
    """Three seeds, one far below the others on validation; every seed ahead of C-SAF-11 on the cell."""
    per_seed = {f"seed{i}": [record("formic", "a", food), record("formic", "b", food + 10)]
                for i, food in ((1, 100), (2, 110), (3, 120))}
    baselines = {"csaf11": [record("csaf11", "a", 50), record("csaf11", "b", 60)], "cardinality": []}
    result = study(per_seed, baselines, {"seed1": 100.0, "seed2": 300.0, "seed3": 320.0})
    # differences 50, 60, 70: mean 60, std 10, t(2) = 4.302653: 60 -+ 24.84, ahead
    (cell,) = result.cells
    assert cell.versus["csaf11"].t.low == pytest.approx(60 - 4.302653 * 10 / 3 ** 0.5, abs=1e-4)
    assert list(cell.versus) == ["csaf11"]  # no Cardinality-MR episodes: no comparison
    lines = target_lines(result)
    # median 300: seed1 at 0.33 x, 0.42 below the 0.75 x line
    assert lines[0].endswith("missed: 1 of 3 seeds collapsed (seed1); the lowest, seed1, is at 0.33 x the median, "
                             "0.42 short.")
    assert "ahead in 1, level in 0, behind in 0 of 1 cells, 19 short" in lines[2]
    assert "1 of 3 seeds (33%)" in collapse_line(result) and "seed1 100.0 (0.33 x)" in collapse_line(result)


def test_evals_must_match_the_runs_one_for_one(tmp_path):
    run = write_selection(tmp_path / "seed1", "novalid.mean", 1.0, {16: 1.0})
    done = subprocess.run([sys.executable, str(ROOT / "scripts" / "seeds_table.py"), "--runs", str(run),
                           "--evals", str(tmp_path / "a"), str(tmp_path / "b")], capture_output=True, text=True,
                          timeout=60)
    assert done.returncode == 2 and "--evals names 2 folders for 1 runs" in done.stderr


def test_an_experiment_in_progress_says_how_many_of_its_seeds_the_table_rests_on(tmp_path):
    runs = [write_selection(tmp_path / "runs" / "seed1", "novalid.mean", 200.0, {16: 110.0}),
            write_selection(tmp_path / "runs" / "seed2", "novalid.mean", 210.0, {16: 120.0})]
    evals = [write_episodes(tmp_path / "evals" / "seed1", [record("formic", "a", 100)]), tmp_path / "evals" / "seed2"]
    baselines = write_episodes(tmp_path / "baselines", [record("csaf11", "a", 90)])

    def table(*args: str) -> subprocess.CompletedProcess:
        return subprocess.run([sys.executable, str(ROOT / "scripts" / "seeds_table.py"), "--runs", *map(str, runs),
                               "--evals", *map(str, evals), "--baselines", str(baselines), *args],
                              capture_output=True, text=True, timeout=60)

    done = table("--planned", "8")
    assert done.returncode == 0, done.stderr
    assert done.stdout.startswith("**In progress: 2 of the 8 seeds fixed in advance have finished training, 1 of "
                                  "them with test episodes.** Everything below rests on those seeds alone; the "
                                  "targets are judged on all 8.\n\n#### Validation\n")
    assert "Intervals are over the 1 seed, not over scenarios." in done.stdout
    assert not table("--planned", "2").stdout.startswith("**In progress")
    missing = subprocess.run([sys.executable, str(ROOT / "scripts" / "seeds_table.py"), "--recipe", "nothing"],
                             capture_output=True, text=True, timeout=60)
    assert missing.returncode == 2 and "--recipe nothing: no models/training/recipe-nothing" in missing.stderr


def test_a_seed_whose_test_episodes_are_still_being_played_is_not_counted_as_tested(tmp_path):
    """Without --runs the table reads each seed's folder only once sealed: a folder being
    played (its plain tail) would put a seed with a few cells into the statistics over seeds."""
    import importlib.util

    spec = importlib.util.spec_from_file_location("seeds_table", ROOT / "scripts" / "seeds_table.py")
    seeds_table = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(seeds_table)
    import gzip

    playing, done, resumed = (write_episodes(tmp_path / name, [record("formic", "a", 100)])
                              for name in ("playing", "done", "resumed"))
    for folder in (done, resumed):  # sealed as EpisodeLog.seal leaves it; resumed: a tail again beside it
        (folder / "episodes.jsonl.gz").write_bytes(gzip.compress((folder / "episodes.jsonl").read_bytes()))
    (done / "episodes.jsonl").unlink()
    assert [seeds_table.sealed(f) for f in (playing, done, resumed, tmp_path / "none")] == [False, True, False, False]


@pytest.mark.parametrize("args", [[], ["--recipe", "paper-v6", "--planned", "8"]])
def test_results_page_seeds_blocks_are_current(args):
    """The results page's seeds blocks are what scripts/seeds_table.py builds from the committed runs
    and evaluation folders: every finished seed of the first recipe, and of paper-v6's eight."""
    script = ROOT / "scripts" / "seeds_table.py"
    done = subprocess.run([sys.executable, str(script), *args, "--check", str(ROOT / "docs" / "results.md")],
                          capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr


@pytest.mark.parametrize("recipe", ["recipe-paper", "recipe-paper-v6"])
def test_every_finished_seed_has_its_current_card_in_seeds_md(recipe):
    """A recipe's SEEDS.md holds scripts/model_card.py's block for every seed that has finished
    (its selection.json), each as the run folder now says."""
    import re

    page = ROOT / "models" / "training" / recipe / "SEEDS.md"
    carded = re.findall(r"<!-- card:begin \(scripts/model_card.py (\S+)\) -->", page.read_text())
    finished = sorted(p.parent.relative_to(ROOT).as_posix()
                      for p in (ROOT / "models" / "training" / recipe).glob("seed*/selection.json"))
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
