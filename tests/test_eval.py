"""The evaluation harness (`formic eval`): CLI contract, shared scenarios, resume, outputs,
aggregation math and the comparison with the paper. Tiny worlds, short episodes."""

from __future__ import annotations

import csv
import json
import shutil
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

from formic_cli.main import cli
from formic_eval import aggregate, food_stats
from formic_eval.matrix import PolicyOptions, Setting, generate_matrix, layout_seed, load_matrix, plan_tasks
from formic_eval.paper import markdown_report, paper_food
from formic_eval.plots import plot_food_vs_team, published_line
from formic_eval.runner import EpisodeLog, evaluate, folder_episodes, run_tasks
from formic_world import Scenario, WorldConfig
from formic_world.scenario_sets import generate_set


def _available(name: str) -> bool:
    from formic_runtime.registry import make_policy

    try:
        make_policy(name)
    except Exception:
        return False
    return True


ALGORITHMS = ["random"] + [n for n in ("csaf", "csaf11", "cardinality", "planner") if _available(n)]
CELL_KEYS = {"algorithm", "size", "agents", "obstacles", "env", "n", "food_mean", "food_std", "step_ms_mean"}
BASE_ARGS = ["eval", "--algorithms", ",".join(ALGORITHMS), "--sizes", "32", "--teams", "4,6", "--obstacles", "0,0.05",
             "--env", "infinite,wipeout", "--scenarios", "2", "--seed", "7", "--steps", "40", "--json"]
N_TASKS = len(ALGORITHMS) * 2 * 2 * 2 * 2  # algorithms x teams x obstacles x envs x scenarios


def _eval(out: Path, *extra: str, workers: int = 1):
    result = CliRunner().invoke(cli, BASE_ARGS + ["--out", str(out), "--workers", str(workers), *extra])
    return result


def _lines(path: Path) -> list[dict]:
    return [json.loads(line) for line in path.read_text().splitlines()]


@pytest.fixture(scope="module")
def base_run(tmp_path_factory):
    """One run through the process pool; the other tests copy its directory."""
    out = tmp_path_factory.mktemp("eval") / "out"
    result = _eval(out, workers=2)
    assert result.exit_code == 0, result.output
    return out, json.loads(result.stdout)


@pytest.fixture
def run_copy(base_run, tmp_path):
    out = tmp_path / "out"
    shutil.copytree(base_run[0], out)
    return out


# ------------------------------------------------------------------------------ CLI contract
def test_json_is_one_object_with_a_cell_per_algorithm_and_setting(base_run):
    out, summary = base_run
    assert summary["episodes"] == {"total": N_TASKS, "done": N_TASKS, "computed": N_TASKS, "reused": 0}
    cells = summary["cells"]
    assert all(CELL_KEYS <= set(c) for c in cells)
    combos = {(c["algorithm"], c["size"], c["agents"], c["obstacles"], c["env"]) for c in cells}
    assert combos == {(a, 32, n, o, e) for a in ALGORITHMS for n in (4, 6) for o in (0.0, 0.05)
                      for e in ("infinite", "wipeout")}
    assert all(c["n"] == 2 and c["steps"] == 40 for c in cells)
    assert all("food_curve_mean" not in c for c in cells)  # curves live in results.json
    if "planner" in ALGORITHMS:
        planner = {(c["agents"], c["obstacles"], c["env"]): c["food_mean"]
                   for c in cells if c["algorithm"] == "planner"}
        for c in cells:
            ref = planner[(c["agents"], c["obstacles"], c["env"])]
            assert c["food_ratio_to_planner"] == (pytest.approx(c["food_mean"] / ref) if ref else None)


# ------------------------------------------------------------------------- shared scenarios
def test_every_algorithm_runs_the_same_stored_scenarios(base_run):
    out, _ = base_run
    seen: dict[tuple, dict[str, set]] = {}
    for r in folder_episodes(out):
        setting = (r["size"], r["agents"], r["obstacles"], r["env"], r["steps"])
        used = seen.setdefault(setting, {}).setdefault(r["algorithm"], set())
        used.add((r["scenario"], r["scenario_digest"], r["seed"]))
    assert len(seen) == 8
    for per_algorithm in seen.values():
        assert set(per_algorithm) == set(ALGORITHMS)
        assert len({frozenset(v) for v in per_algorithm.values()}) == 1
    files = sorted((out / "scenarios").glob("*.json"))
    assert len(files) == 16
    for f in files:  # stored plain data that regenerates bit-identically from its seed
        scenario = Scenario.load(f)
        assert scenario.regenerate().to_json() == f.read_text()


def test_layout_seeds_follow_the_seed_option_and_the_layout_parameters():
    assert layout_seed(7, 32, 0.0, "infinite") == layout_seed(7, 32, 0.0, "infinite")
    assert layout_seed(7, 32, 0.0, "infinite") != layout_seed(8, 32, 0.0, "infinite")
    assert layout_seed(7, 32, 0.0, "infinite") != layout_seed(7, 32, 0.05, "infinite")
    assert layout_seed(7, 32, 0.0, "infinite") != layout_seed(7, 64, 0.0, "infinite")


def test_generated_matrix_pairs_layouts(tmp_path):
    settings = [Setting(32, n, 0.0, env, 40) for n in (4, 6) for env in ("infinite", "wipeout")]
    matrix = generate_matrix(settings, 2, seed=3, directory=tmp_path)
    layouts = {
        s: [(sc.resources, sc.obstacles) for sc in (Scenario.load(x.path) for x in stored)]
        for s, stored in matrix.items()
    }
    assert len({tuple(v) for v in layouts.values()}) == 1
    wipeout = Scenario.load(matrix[settings[1]][0].path)
    assert wipeout.config.wipeouts == 3 and wipeout.config.wipeout_steps == 10 and len(wipeout.wipeout_starts) == 3


# ---------------------------------------------------------------------------------- resume
def test_rerun_computes_nothing_and_prints_one_json_object(base_run, run_copy):
    before = (run_copy / "episodes.jsonl").read_text()
    result = _eval(run_copy)
    assert result.exit_code == 0 and "\n" not in result.stdout.strip()
    summary = json.loads(result.stdout)
    assert summary["episodes"]["computed"] == 0 and summary["episodes"]["reused"] == N_TASKS
    assert (run_copy / "episodes.jsonl").read_text() == before
    strip = lambda cells: [{k: v for k, v in c.items() if "ms" not in k} for c in cells]  # noqa: E731
    assert strip(summary["cells"]) == strip(base_run[1]["cells"])


def test_torn_last_line_is_cut_and_that_episode_redone(base_run, run_copy):
    log = run_copy / "episodes.jsonl"
    data = log.read_bytes()
    log.write_bytes(data[: len(data) - 40])  # killed in the middle of writing the last record
    summary = json.loads(_eval(run_copy).stdout)
    assert summary["episodes"]["computed"] == 1 and summary["log"]["torn_line_removed"]
    records = _lines(log)
    assert len(records) == N_TASKS == len({r["key"] for r in records})
    original = {r["key"]: r["food"] for r in folder_episodes(base_run[0])}
    assert {r["key"]: r["food"] for r in records} == original  # episodes are deterministic


def test_interrupt_keeps_finished_episodes_and_resume_finishes(tmp_path):
    settings = [Setting(32, 4, 0.0, "infinite", 30)]
    matrix = generate_matrix(settings, 3, seed=1, directory=tmp_path / "scenarios")
    tasks = plan_tasks(matrix, ["random"], PolicyOptions())
    log, done = EpisodeLog(tmp_path / "episodes.jsonl"), {}

    def ctrl_c_after_two(record):
        if len(done) == 2:
            raise KeyboardInterrupt

    stats = run_tasks(tasks, log, done, workers=1, progress=False, on_record=ctrl_c_after_two)
    assert stats.interrupted and stats.computed == 2
    assert len(_lines(log.path)) == 2
    summary = evaluate(matrix, ["random"], PolicyOptions(), tmp_path, workers=1, progress=False)
    assert summary["episodes"] == {"total": 3, "done": 3, "computed": 1, "reused": 2}
    assert not summary["interrupted"] and len(_lines(log.path)) == 3


def test_a_second_evaluation_into_a_folder_in_use_is_refused_at_once(tmp_path):
    from formic_world.files import held_directory

    args = ["eval", "--algorithms", "random", "--sizes", "16", "--teams", "2", "--obstacles", "0", "--env",
            "infinite", "--scenarios", "1", "--steps", "8", "--workers", "1", "--out", str(tmp_path / "out")]
    with held_directory(tmp_path / "out"):  # another `formic eval` running there
        refused = CliRunner().invoke(cli, args)
    assert refused.exit_code == 1 and "is in use by another process" in refused.output, refused.output
    assert not (tmp_path / "out" / "episodes.jsonl").exists()
    assert CliRunner().invoke(cli, args).exit_code == 0  # free again


@pytest.mark.parametrize("signum", ["SIGTERM", "SIGHUP"])
def test_a_stop_signal_to_a_background_eval_stops_its_workers_and_keeps_its_episodes(tmp_path, signum):
    """`formic eval &` ignores Ctrl-C (the shell's rule for background jobs): SIGTERM or SIGHUP
    stop it as Ctrl-C would, with no worker writing into a closed pipe, and a rerun resumes."""
    import os
    import signal
    import subprocess
    import sys
    import time

    args = [sys.executable, "-m", "formic_cli.main", "eval", "--algorithms", "random", "--sizes", "32", "--teams",
            "4", "--obstacles", "0", "--env", "infinite", "--scenarios", "60", "--steps", "400", "--workers", "2",
            "--out", str(tmp_path / "out")]
    log = tmp_path / "out" / "episodes.jsonl"
    run = subprocess.Popen(args, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                           preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_IGN))
    try:
        deadline = time.monotonic() + 90
        while not (log.exists() and log.read_text().count("\n") >= 2) and time.monotonic() < deadline:
            time.sleep(0.05)
        run.send_signal(getattr(signal, signum))
        out, err = run.communicate(timeout=60)
    finally:
        if run.poll() is None:
            os.kill(run.pid, signal.SIGKILL)
            run.wait()
    assert run.returncode == 130, err[-2000:]
    assert "interrupted: rerun the same command to resume" in err and "Traceback" not in err, err[-2000:]
    kept = len(_lines(log))
    assert 2 <= kept < 60
    resumed = subprocess.run([*args, "--scenarios", "60", "--json"], capture_output=True, text=True, timeout=300)
    assert resumed.returncode == 0, resumed.stderr[-2000:]
    assert json.loads(resumed.stdout)["episodes"] == {"total": 60, "done": 60, "computed": 60 - kept, "reused": kept}


def test_the_report_names_the_workers_each_episode_was_timed_with(run_copy):
    """Decision times depend on how many worker processes shared the cores: each record keeps
    its count, and a resumed call's report names every count among its episodes, not its own."""
    log = run_copy / "episodes.jsonl"
    records = _lines(log)
    assert {r["workers"] for r in records} == {2}
    log.write_text("".join(json.dumps(r) + "\n" for r in records[:-1]))  # one episode to run again
    result = _eval(run_copy, workers=2)
    assert result.exit_code == 0, result.output
    summary = json.loads(result.stdout)
    assert summary["episodes"]["computed"] == 1 and summary["episode_workers"] == "1 or 2"
    assert _lines(log)[-1]["workers"] == 1  # one pending episode runs in this process
    assert "(with 1 or 2 worker process(es) sharing its cores)" in (run_copy / "results.md").read_text()
    older = [{k: v for k, v in r.items() if k != "workers"} if i == 0 else r for i, r in enumerate(_lines(log))]
    log.write_text("".join(json.dumps(r) + "\n" for r in older))  # as logged before records kept the count
    result = CliRunner().invoke(cli, ["eval", "--report", "--out", str(run_copy), "--json"])
    assert result.exit_code == 0, result.output
    assert json.loads(result.stdout)["episode_workers"] == "1 or 2 or an unrecorded number of"


# --------------------------------------------------------------------------------- outputs
def test_csv_json_figures_and_report_parse(base_run):
    out, summary = base_run
    with open(out / "results.csv") as f:
        cells = list(csv.DictReader(f))
    assert len(cells) == len(summary["cells"])
    assert float(cells[0]["food_mean"]) == pytest.approx(summary["cells"][0]["food_mean"])
    with open(out / "episodes.csv") as f:
        assert len(list(csv.DictReader(f))) == N_TASKS
    with open(out / "curves.csv") as f:
        assert len(list(csv.DictReader(f))) == len(cells) * 40
    full = json.loads((out / "results.json").read_text())
    assert len(full["episodes"]) == N_TASKS
    curve = full["cells"][0]["food_curve_mean"]
    assert len(curve) == 40 and curve[-1] == pytest.approx(full["cells"][0]["food_mean"])
    for name in ("food_vs_team", "time_per_step", "food_vs_time"):
        png = out / f"{name}_s32_t40.png"
        assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    report = (out / "results.md").read_text()
    assert "| size | steps | setting | algorithm |" in report
    assert report.count("\n| 32 | 40 |") == len(cells)


# ----------------------------------------------------------------------- stored scenarios
def test_scenario_directory_supplies_the_settings(tmp_path):
    for n in (4, 5):
        generate_set(WorldConfig(height=32, width=32, n_agents=n, episode_steps=30), 11, 2, tmp_path / "set")
    result = CliRunner().invoke(cli, ["eval", "--algorithms", "random", "--scenarios", str(tmp_path / "set"),
                                      "--out", str(tmp_path / "out"), "--workers", "1", "--json"])
    assert result.exit_code == 0, result.output
    cells = json.loads(result.stdout)["cells"]
    got = [(c["agents"], c["n"], c["steps"], c["env"]) for c in cells]
    assert got == [(4, 2, 30, "infinite"), (5, 2, 30, "infinite")]
    assert not (tmp_path / "out" / "scenarios").exists()
    only = load_matrix(tmp_path / "set", teams=[5], envs=["infinite"], steps=20)
    assert list(only) == [Setting(32, 5, 0.0, "infinite", 20)] and len(only[Setting(32, 5, 0.0, "infinite", 20)]) == 2
    with pytest.raises(ValueError, match="exceeds"):
        load_matrix(tmp_path / "set", steps=31)


def test_corrupted_scenario_file_is_a_clear_error(tmp_path):
    generate_set(WorldConfig(height=32, width=32, n_agents=4, episode_steps=30), 0, 1, tmp_path)
    (tmp_path / "broken.json").write_text('{"format": "formic-scenario", "version": 1, "seed": ')
    result = CliRunner().invoke(cli, ["eval", "--algorithms", "random", "--scenarios", str(tmp_path),
                                      "--out", str(tmp_path / "out")])
    assert result.exit_code == 1
    assert "broken.json" in result.output and "not valid JSON" in result.output


def test_missing_model_is_a_clear_error(tmp_path):
    result = CliRunner().invoke(cli, ["eval", "--algorithms", "formic,random", "--model", str(tmp_path / "none.pt"),
                                      "--sizes", "32", "--teams", "4", "--scenarios", "1", "--out", str(tmp_path)])
    assert result.exit_code == 1 and "no model at" in result.output and "none.pt" in result.output


def test_no_pheromones_and_greedy_apply_to_the_learned_policy_only(tmp_path, monkeypatch):
    matrix = generate_matrix([Setting(32, 4, 0.0, "infinite", 20)], 1, seed=0, directory=tmp_path)
    options = PolicyOptions(model="m.pt", model_digest="abc", greedy=True, no_pheromones=True)
    tasks = {t.algorithm: t for t in plan_tasks(matrix, ["formic", "random"], options)}
    formic = tasks["formic"]
    assert (formic.variant, formic.no_pheromones, formic.greedy) == ("greedy+no-pheromones", True, True)
    assert (tasks["random"].variant, tasks["random"].no_pheromones, tasks["random"].model) == ("", False, None)
    assert tasks["formic"].key != tasks["random"].key

    import formic_runtime.episode
    import formic_runtime.registry
    from formic_agent.learned import LearnedPolicy
    from formic_agent.inputs import NETWORK_PRESETS
    from formic_agent.network import ForMICNet

    seen = []
    real = formic_runtime.episode.run_episode
    untrained = LearnedPolicy(ForMICNet(NETWORK_PRESETS["cpu"]))  # "m.pt" does not exist: a fresh network
    monkeypatch.setattr(formic_runtime.registry, "make_policy", lambda name, model=None, greedy=False: untrained)

    def spy(scenario, *args, **kwargs):
        seen.append(scenario.config.pheromones_visible)
        return real(scenario, *args, **kwargs)

    monkeypatch.setattr(formic_runtime.episode, "run_episode", spy)
    from formic_eval.runner import run_task

    record = run_task(tasks["formic"])
    assert seen == [False] and record["variant"] == "greedy+no-pheromones" and record["model"] == "abc"


def test_pheromone_variant_applies_to_every_world_and_labels_every_cell(tmp_path, monkeypatch):
    """`--variant flat|noisy|random` (the paper's out-of-distribution trail tests) changes every
    algorithm's world, not the stored scenario, and keeps its episodes apart from the standard ones."""
    matrix = generate_matrix([Setting(32, 4, 0.0, "infinite", 20)], 1, seed=0, directory=tmp_path / "scen")
    options = PolicyOptions(model="m.pt", model_digest="abc", no_pheromones=True, pheromone_variant="flat")
    tasks = {t.algorithm: t for t in plan_tasks(matrix, ["formic", "random"], options)}
    assert (tasks["formic"].variant, tasks["random"].variant) == ("no-pheromones+trails-flat", "trails-flat")
    plain = {t.algorithm: t for t in plan_tasks(matrix, ["random"], PolicyOptions())}
    assert plain["random"].variant == "" and plain["random"].key != tasks["random"].key

    import formic_runtime.episode

    seen = []
    real = formic_runtime.episode.run_episode

    def spy(scenario, *args, **kwargs):
        seen.append(scenario.config.pheromone_variant)
        return real(scenario, *args, **kwargs)

    monkeypatch.setattr(formic_runtime.episode, "run_episode", spy)
    from formic_eval.runner import run_task

    record = run_task(tasks["random"])
    stored = Scenario.load(next(iter(matrix.values()))[0].path)
    assert seen == ["flat"] and record["variant"] == "trails-flat" and stored.config.pheromone_variant == "standard"
    result = CliRunner().invoke(cli, ["eval", "--algorithms", "random", "--variant", "sideways", "--out", str(tmp_path)])
    assert result.exit_code == 2 and "sideways" in result.output


# ------------------------------------------------------------------------------------ math
def test_food_stats_on_known_values():
    stats = food_stats([1.0, 2.0, 3.0, 4.0])
    assert stats["food_mean"] == 2.5
    assert stats["food_std"] == pytest.approx(np.sqrt(5 / 3))  # sample std, ddof=1
    assert (stats["food_min"], stats["food_max"]) == (1.0, 4.0)
    assert food_stats([7.0])["food_std"] == 0.0


def _record(algorithm: str, seed: int, food: float, step_ms: float, curve: list[float], agents: int = 4) -> dict:
    return {"algorithm": algorithm, "variant": "", "size": 32, "agents": agents, "obstacles": 0.0, "env": "infinite",
            "steps": len(curve), "seed": seed, "scenario": f"s{seed}.json", "food": food, "step_ms_mean": step_ms,
            "world_step_ms_mean": 1.0, "food_curve": curve}


def test_aggregate_means_stds_curves_times_and_planner_ratio():
    records = [
        _record("random", 1, 2.0, 1.0, [0.0, 1.0, 2.0]),
        _record("random", 2, 6.0, 3.0, [1.0, 3.0, 6.0]),
        _record("planner", 1, 8.0, 4.0, [2.0, 5.0, 8.0]),
        _record("planner", 2, 12.0, 8.0, [4.0, 8.0, 12.0]),
    ]
    cells = {c["algorithm"]: c for c in aggregate(records)}
    rnd = cells["random"]
    assert (rnd["n"], rnd["food_mean"], rnd["food_std"]) == (2, 4.0, pytest.approx(np.sqrt(8.0)))
    assert rnd["food_curve_mean"] == [0.5, 2.0, 4.0]
    assert rnd["step_ms_mean"] == 2.0 and rnd["agent_step_ms_mean"] == 0.5
    assert rnd["food_ratio_to_planner"] == pytest.approx(0.4) and cells["planner"]["food_ratio_to_planner"] == 1.0
    assert rnd["seeds"] == [1, 2] and rnd["paper_food"] is None


def test_aggregate_refuses_to_mix_two_models_in_one_cell():
    first, second = _record("formic", 1, 5.0, 1.0, [5.0]), _record("formic", 2, 7.0, 1.0, [7.0])
    first["model"], second["model"] = "a" * 64, "b" * 64
    with pytest.raises(ValueError, match="2 different models"):
        aggregate([first, second])
    second["model"] = first["model"]
    assert aggregate([first, second])[0]["food_mean"] == 6.0


def test_report_sets_our_numbers_beside_the_papers():
    def cell(algorithm, agents, env="infinite", obstacles=0.0, variant=""):
        return {"algorithm": algorithm, "variant": variant, "size": 128, "agents": agents, "obstacles": obstacles,
                "env": env, "steps": 1024}

    assert paper_food(cell("formic", 16)) == 249
    assert paper_food(cell("formic", 16) | {"steps": 512}) is None  # the paper's totals are 1024-step
    assert paper_food(cell("csaf11-ref", 64)) == paper_food(cell("csaf11", 64)) == 158
    assert paper_food(cell("planner", 128, env="finite")) == 624
    assert paper_food(cell("csaf11", 32, obstacles=0.05)) == 120
    assert paper_food(cell("csaf", 32, obstacles=0.05)) is None
    assert paper_food(cell("planner", 16, env="wipeout")) is None
    assert paper_food(cell("formic", 32, variant="no-pheromones")) == 267
    assert paper_food(cell("formic", 32) | {"size": 64}) is None

    records = [_record(a, s, f, 1.0, [0.0] * 1023 + [f], agents=16) | {"size": 128}
               for a, foods in (("formic", (240.0, 260.0)), ("planner", (270.0, 290.0))) for s, f in zip((1, 2), foods)]
    cells = aggregate(records)
    run = {"algorithms": ["formic", "planner"], "scenarios": "x", "workers": 2, "episode_workers": "2",
           "episodes": {"total": 4, "done": 4, "computed": 4, "reused": 0}}
    report = markdown_report(cells, run)
    assert "| infinite, 0% obstacles | ForMIC | 16 | 250.0 ± 14.1 | 249 | 1.00 | 0.89 | 0.90 |" in report
    assert "| infinite, 0% obstacles | centralized | 16 | 280.0 ± 14.1 | 276 | 1.01 | 1.00 | 1.00 |" in report


def test_the_food_figure_draws_the_papers_formic_beside_ours(tmp_path):
    """Fig. 5's figure: the paper's ForMIC where it published one (128x128, 1024 steps), nothing
    elsewhere; the figure draws with and without it."""
    def cell(agents, size=128, env="infinite"):
        return {"algorithm": "formic", "variant": "", "size": size, "agents": agents, "obstacles": 0.0, "env": env,
                "steps": 1024, "food_mean": 100.0 + agents, "food_std": 5.0}

    assert published_line([cell(16), cell(32), cell(128)]) == [(16, 249.0), (32, 403.0), (128, 862.0)]
    assert published_line([cell(16, env="wipeout")]) == [(16, 220.0)]
    assert published_line([cell(16, size=64)]) == []
    for cells in ([cell(16), cell(32), cell(16, env="wipeout")], [cell(16, size=64), cell(32, size=64)]):
        png = plot_food_vs_team(cells, tmp_path / f"s{cells[0]['size']}.png")
        assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_a_model_with_another_field_of_view_sees_the_same_layout_through_its_window(tmp_path):
    """Table III's models (field of view 5 or 21) play the stored 11x11 scenarios: the world gives
    each the window it was trained on; run with a mismatched window it stops with a clear error."""
    import dataclasses

    import torch

    from formic_agent.checkpoint import save_checkpoint
    from formic_agent.inputs import NETWORK_PRESETS
    from formic_agent.network import ForMICNet

    torch.manual_seed(0)
    model = tmp_path / "fov5.pt"
    save_checkpoint(model, ForMICNet(dataclasses.replace(NETWORK_PRESETS["cpu"], view_size=5)))
    generate_set(WorldConfig(height=32, width=32, n_agents=4, episode_steps=20), 3, 1, tmp_path / "set")
    result = CliRunner().invoke(cli, ["eval", "--algorithms", "formic", "--model", str(model), "--scenarios",
                                      str(tmp_path / "set"), "--out", str(tmp_path / "out"), "--workers", "1", "--json"])
    assert result.exit_code == 0, result.output
    assert [c["n"] for c in json.loads(result.stdout)["cells"]] == [1]
    result = CliRunner().invoke(cli, ["sim", "--policy", "formic", "--model", str(model), "--agents", "4",
                                      "--size", "32", "--steps", "5"])
    assert result.exit_code == 1 and "sees 5x5 cells, the world gives 11x11: run the world with --view-size 5" \
        in result.output, result.output
