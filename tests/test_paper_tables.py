"""The paper's Tables I-III from evaluation folders (issue 26): relative performance per cell."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

from formic_eval.tables import ROWS, Relative, cell_ratios, cell_verdicts, model_episodes

ROOT = Path(__file__).resolve().parents[1]
CELLS = [(env, obstacles, n) for env in ("infinite", "wipeout") for obstacles in (0.0, 0.05) for n in (16, 32, 64, 128)]


def episodes(food, variant: str = "", model: str = "m", scenarios=("a", "b")) -> list[dict]:
    """Two scenarios per cell of the tables' 16; ``food(env, obstacles, agents)`` gives the food."""
    out = []
    for env, obstacles, n in CELLS:
        for digest in scenarios:
            out.append({"key": f"{variant}|{env}|{obstacles}|{n}|{digest}", "algorithm": "formic", "variant": variant,
                        "model": model, "size": 128, "steps": 1024, "agents": n, "obstacles": obstacles, "env": env,
                        "seed": 7, "scenario": digest, "scenario_digest": f"{env}{obstacles}{n}{digest}",
                        "food": food(env, obstacles, n)})
    return out


def write(folder: Path, *groups: list[dict]) -> None:
    folder.mkdir(parents=True, exist_ok=True)
    with open(folder / "episodes.jsonl", "a") as log:
        for records in groups:
            log.writelines(json.dumps(r) + "\n" for r in records)


def run_tables(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, str(ROOT / "scripts" / "paper_tables.py"), *args],
                          capture_output=True, text=True, timeout=60)


def test_every_row_of_the_three_tables_is_a_recipe_switch():
    from formic_trainer.recipes.files import load_recipe

    switches = set(load_recipe("paper").switches)
    assert {row.switch for row in ROWS} - {"reference"} <= switches
    assert [row.table for row in ROWS].count("I") == 5 and len(ROWS) == 10


def test_relative_performance_is_per_cell_on_shared_scenarios_then_mean_and_std_over_cells(tmp_path):
    reference = episodes(lambda env, o, n: 100.0)
    row = episodes(lambda env, o, n: 80.0 if env == "infinite" else 60.0)
    ratios = cell_ratios(row, reference)
    assert len(ratios) == 16 and ratios[("infinite", 0.05, 32)] == 0.8 and ratios[("wipeout", 0.0, 16)] == 0.6
    found = Relative.of(ratios)
    assert (found.mean, found.cells) == (pytest.approx(70.0), 16)
    assert found.std == pytest.approx((1600 / 15) ** 0.5)  # sample std of eight 80s and eight 60s
    assert found.by_team == {n: pytest.approx(70.0) for n in (16, 32, 64, 128)}
    # a scenario only one side played is left out of its cell
    extra = episodes(lambda env, o, n: 0.0, scenarios=("c",))
    assert cell_ratios(row + extra, reference) == ratios


def test_a_cell_is_behind_level_or_ahead_by_its_paired_interval():
    scenarios = ("a", "b", "c")
    reference = episodes(lambda env, o, n: 100.0, scenarios=scenarios)
    # per scenario a, b, c: the 95% interval of -20 -21 -19 is -20 ± 2.5 (behind), of -10 +10 0 spans
    # zero (level), of +10 +11 +9 is ahead; no difference at 128 agents is level
    shift = {16: (-20.0, -21.0, -19.0), 32: (-10.0, 10.0, 0.0), 64: (10.0, 11.0, 9.0), 128: (0.0, 0.0, 0.0)}
    row = [dict(r, food=r["food"] + shift[r["agents"]][scenarios.index(r["scenario"])]) for r in reference]
    assert cell_verdicts(row, reference) == (4, 8, 4)  # 4 cells per team size


def test_the_script_prints_each_table_beside_the_paper_and_names_rows_not_yet_evaluated(tmp_path):
    root = tmp_path / "tables"
    write(root / "reference", episodes(lambda env, o, n: 100.0),
          episodes(lambda env, o, n: 50.0, variant="no-pheromones"))  # the same model, the channel empty
    write(root / "no-curriculum", episodes(lambda env, o, n: 80.0 if env == "infinite" else 60.0, model="nc"))
    outside = [dict(r, env="finite", key=r["key"] + "f") for r in episodes(lambda env, o, n: 1.0, model="nc")]
    write(root / "no-curriculum", outside)  # finite resources: not one of the tables' cells
    write(root / "fov5", episodes(lambda env, o, n: float(n), model="f5"))  # 16%..128% by team size: std 44.3
    seeds = [tmp_path / "seed1", tmp_path / "seed2"]
    write(seeds[0], episodes(lambda env, o, n: 90.0, model="s1"))
    write(seeds[1], episodes(lambda env, o, n: 110.0, model="s2"))
    done = run_tables(str(root), "--seeds", *map(str, seeds), "--row-seeds")  # none: not the repository's
    assert done.returncode == 0, done.stderr
    lines = done.stdout.splitlines()
    assert "| Training without pheromone curriculum | 70.0% ± 10.3% | 75.89% ± 7.00% | 70% | 70% | 70% | 70% | 16 " \
        "| 16 / 0 / 0 |" \
        in lines
    empty = ("| Testing without pheromones (empty channel) | 50.0% ± 0.0% | 65.89% ± 8.73% "
             "| 50% | 50% | 50% | 50% | 16 | 16 / 0 / 0 |")
    assert empty in lines
    # below the reference's 100 food at 16-64 agents, above it at 128
    fov5 = "| FOV 5 | 60.0% ± 44.3% | 59.61% ± 11.00% | 16% | 32% | 64% | 128% | 16 | 12 / 0 / 4 |"
    assert fov5 in lines, done.stdout
    missing = next(line for line in lines if line.startswith("| Training without invalid action pruning |"))
    assert f"not evaluated yet ({root / 'no-pruning'})" in missing and missing.endswith("| 0 | – |")
    assert "Noise scale of one seed (the unchanged recipe's 2 seeds, each over their mean, 32 seed-cells): ± 10.2%." \
        in lines
    assert [line for line in lines if line.startswith("#### ")] == [
        "#### Table I: ablations", "#### Table II: learning and non-learning agents in teams of 32",
        "#### Table III: field of view"]


def test_a_row_trained_with_more_seeds_gets_a_line_per_seed_and_the_mean_over_seeds(tmp_path):
    """--row-seeds: another folder of rows (another training seed, no reference of its own) adds,
    under a row it evaluated, that seed's line and the mean over the row's seeds, per scenario
    against ROOT's reference; rows it lacks keep one line."""
    root, seed2 = tmp_path / "tables", tmp_path / "tables-seed2"
    scenarios = ("a", "b", "c")
    write(root / "reference", episodes(lambda env, o, n: 100.0, scenarios=scenarios))
    write(root / "learning-32-0", episodes(lambda env, o, n: 40.0, model="s1", scenarios=scenarios))
    write(root / "fov5", episodes(lambda env, o, n: 50.0, model="f5", scenarios=scenarios))
    # seed 2: 120 food on scenarios a and b, 110 on c (ahead everywhere); the mean over the two
    # seeds, 80 80 75, is behind the reference in every cell
    seed2_food = [dict(r, food=110.0 if r["scenario"] == "c" else 120.0)
                  for r in episodes(lambda env, o, n: 0.0, model="s2", scenarios=scenarios)]
    write(seed2 / "learning-32-0", seed2_food)
    done = run_tables(str(root), "--seeds", "--row-seeds", str(seed2))
    assert done.returncode == 0, done.stderr
    lines = done.stdout.splitlines()
    at = lines.index("| 32 learning + 0 non-learning agents | 40.0% ± 0.0% | 105.33% ± 10.88% | 40% | 40% | 40% "
                     "| 40% | 16 | 16 / 0 / 0 |")
    seed_line = f"| ↳ another seed: `{seed2}` | 116.7% ± 0.0% |  | 117% | 117% | 117% | 117% | 16 | 0 / 0 / 16 |"
    mean_line = "| ↳ mean over its 2 seeds | 78.3% ± 0.0% |  | 78% | 78% | 78% | 78% | 16 | 16 / 0 / 0 |"
    assert lines[at + 1:at + 3] == [seed_line, mean_line], done.stdout
    fov5 = next(i for i, line in enumerate(lines) if line.startswith("| FOV 5 |"))
    assert lines[fov5 + 1].startswith("| FOV 21 | not evaluated yet")
    assert not any("Noise scale" in line for line in lines)  # --seeds given no folders


def test_a_reference_trained_with_more_seeds_becomes_the_seeds_mean_for_every_row(tmp_path):
    """A --row-seeds folder holding the reference too: every row (each seed's line and the mean)
    is relative to the reference seeds' mean per scenario, and their spread is printed as the
    noise scale at the tables' budget."""
    root, seed2 = tmp_path / "tables", tmp_path / "tables-seed2"
    write(root / "reference", episodes(lambda env, o, n: 100.0),
          episodes(lambda env, o, n: 45.0, variant="no-pheromones"))
    write(seed2 / "reference", episodes(lambda env, o, n: 80.0, model="r2"),
          episodes(lambda env, o, n: 27.0, variant="no-pheromones", model="r2"))
    write(root / "fov5", episodes(lambda env, o, n: 45.0, model="f5"))  # the reference seeds' mean is 90
    done = run_tables(str(root), "--seeds", "--row-seeds", str(seed2))
    assert done.returncode == 0, done.stderr
    lines = done.stdout.splitlines()
    assert lines[0].startswith(f"Relative to the reference row's mean over its 2 seeds (`{root / 'reference'}`, "
                               f"`{seed2 / 'reference'}`; per scenario, the seeds' mean food) on the same scenarios")
    # seed 1 at 100 and seed 2 at 80 are 111.1% and 88.9% of their mean: sample std of 32 seed-cells
    assert "At the tables' budget (the reference row's 2 seeds, each over their mean, 32 seed-cells): ± 11.3%." in lines
    assert "| FOV 5 | 50.0% ± 0.0% | 59.61% ± 11.00% | 50% | 50% | 50% | 50% | 16 | 16 / 0 / 0 |" in lines
    at = next(i for i, line in enumerate(lines) if line.startswith("| Testing without pheromones"))
    assert lines[at].startswith("| Testing without pheromones (empty channel) | 50.0% ± 0.0% |")  # 45 / 90
    assert lines[at + 1].startswith(f"| ↳ another seed: `{seed2}` | 30.0% ± 0.0% |")  # 27 / 90
    assert lines[at + 2].startswith("| ↳ mean over its 2 seeds | 40.0% ± 0.0% |")  # 36 / 90


def test_a_folder_with_two_models_in_one_row_is_refused(tmp_path):
    root = tmp_path / "tables"
    write(root / "reference", episodes(lambda env, o, n: 100.0))
    write(root / "fov21", episodes(lambda env, o, n: 100.0, model="one"),
          [dict(r, key=r["key"] + "x", scenario_digest=r["scenario_digest"] + "x")
           for r in episodes(lambda env, o, n: 100.0, model="two")])
    with pytest.raises(ValueError, match="several models"):
        model_episodes(root / "fov21", "")
    done = run_tables(str(root), "--seeds", "--row-seeds")
    assert done.returncode == 1 and "several models (one, two)" in done.stderr


def test_eval_tables_plans_each_finished_run_as_its_rows_are_tested(tmp_path):
    """scripts/eval_tables.py: the reference as trained first, then every row's test in ROWS
    order (the reference and the blind run with the channel empty), runs without a model
    skipped; every command it prints is one `formic eval` accepts."""
    import shlex

    from formic_cli.main import cli

    for run in ("reference", "no-pheromones", "fov5"):
        (tmp_path / "runs" / run).mkdir(parents=True)
        (tmp_path / "runs" / run / "model.pt").write_bytes(b"")
    done = subprocess.run([sys.executable, str(ROOT / "scripts" / "eval_tables.py"), str(tmp_path / "runs"),
                           str(tmp_path / "eval"), "--dry-run", "--workers", "3"],
                          capture_output=True, text=True, timeout=60, env={"FORMIC": "formic", "PATH": ""})
    assert done.returncode == 0, done.stderr
    lines = done.stdout.splitlines()
    planned = [line.split(": ", 1) for line in lines if not line.endswith("skipped")]
    assert [head for head, _ in planned] == ["reference (as trained)", "no-pheromones (the channel empty)",
                                             "reference (the channel empty)", "fov5 (as trained)"]
    assert len(lines) == 11  # the reference twice and the ten rows' other nine runs, once each
    for head, text in planned:
        args = shlex.split(text)
        assert args[:2] == ["formic", "eval"] and ("--no-pheromones" in args) == ("channel empty" in head)
        assert args[args.index("--out") + 1] == str(tmp_path / "eval" / head.split()[0])
        context = cli.commands["eval"].make_context("eval", args[2:])  # parses, runs nothing
        assert context.params["workers"] == 3 and context.params["scenarios"] == "20"


def test_results_page_tables_block_is_current():
    """The results page's Tables I-III block is what scripts/paper_tables.py builds from the committed
    evaluation folders (its defaults: eval/tables and every eval/recipe-paper/seedS)."""
    done = run_tables("--check", str(ROOT / "docs" / "results.md"))
    assert done.returncode == 0, done.stderr
