"""Paired comparisons (formic_eval.paired): per-scenario differences, their t interval, and
which episodes pair up (same scenario; for wipeouts, the same layout)."""

from __future__ import annotations

import math

import pytest

from formic_eval.paired import compare, layout_key, paired_difference


def record(algorithm, food, seed, env="infinite", agents=16, digest=None):
    return {"algorithm": algorithm, "variant": "", "size": 32, "agents": agents, "obstacles": 0.0, "env": env,
            "steps": 64, "seed": seed, "scenario_digest": digest or f"{env}{seed}", "food": food}


def test_difference_and_interval_by_hand():
    d = paired_difference([12, 15, 11, 18], [10, 10, 10, 10])
    # differences 2, 5, 1, 8: mean 4, sample std sqrt(10); t(0.975, 3) = 3.182446305
    half = 3.182446305284263 * math.sqrt(10) / 2
    assert (d.n, d.mean, d.base_mean) == (4, 4.0, 10.0)
    assert d.low == pytest.approx(4 - half, abs=1e-9) and d.high == pytest.approx(4 + half, abs=1e-9)
    assert not d.significant  # 4 - 5.03 < 0
    assert d.percent() == pytest.approx((40.0, 10 * (4 - half), 10 * (4 + half)))
    assert paired_difference([3, 4, 5], [1, 2, 3]).significant  # a constant +2: zero-width interval


def test_one_pair_has_no_interval_and_bad_input_is_refused():
    d = paired_difference([5], [3])
    assert d.mean == 2 and math.isinf(d.low) and math.isinf(d.high) and not d.significant
    with pytest.raises(ValueError, match="pairs"):
        paired_difference([1, 2], [1])
    with pytest.raises(ValueError, match="pairs"):
        paired_difference([], [])


def test_only_shared_scenarios_pair_per_setting():
    ours = [record("formic", 10, 1), record("formic", 20, 2), record("formic", 30, 3),
            record("formic", 50, 1, agents=32)]
    theirs = [record("csaf11", 8, 1), record("csaf11", 17, 2), record("csaf11", 99, 4),
              record("csaf11", 45, 1, agents=32)]
    found = compare(ours, theirs)
    assert set(found) == {(32, 16, 0.0, "infinite", 64), (32, 32, 0.0, "infinite", 64)}
    assert (found[(32, 16, 0.0, "infinite", 64)].n, found[(32, 16, 0.0, "infinite", 64)].mean) == (2, 2.5)
    assert found[(32, 32, 0.0, "infinite", 64)].mean == 5


def test_wipeouts_pair_with_the_same_layout():
    plain = [record("formic", 100, s) for s in (1, 2)]
    wiped = [record("formic", f, s, env="wipeout") for f, s in ((90, 1), (70, 2))]
    assert compare(wiped, plain) == {}  # different scenarios: nothing pairs by scenario
    cost = compare(wiped, plain, key=layout_key)[(32, 16, 0.0, 64)]
    assert (cost.n, cost.mean, cost.base_mean) == (2, -20.0, 100.0)


def test_a_scenario_run_twice_is_an_error():
    twice = [record("formic", 10, 1), record("formic", 11, 1)]
    with pytest.raises(ValueError, match="two episodes on one scenario"):
        compare(twice, [record("csaf11", 8, 1)])


def test_results_page_and_readme_summary_are_current():
    """docs/results.md's results block and README.md's summary block are what
    scripts/readme_results.py builds from the committed evaluation folders, byte for byte
    (rebuild both with --write after an evaluation)."""
    import subprocess
    import sys
    from pathlib import Path

    root = Path(__file__).resolve().parents[1]
    page, readme = root / "docs" / "results.md", root / "README.md"
    assert "<!-- results:begin (scripts/readme_results.py) -->" in page.read_text()
    assert "<!-- summary:begin (scripts/readme_results.py) -->" in readme.read_text()
    done = subprocess.run([sys.executable, str(root / "scripts" / "readme_results.py"), "--check", str(page), str(readme)],
                          capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr


def test_a_stale_readme_summary_fails_the_check(tmp_path):
    """--check compares the summary byte for byte: one changed number in a copy of the README fails
    it, and names the command that rebuilds it."""
    import subprocess
    import sys
    from pathlib import Path

    root = Path(__file__).resolve().parents[1]
    text = (root / "README.md").read_text()
    start = text.index("<!-- summary:begin (scripts/readme_results.py) -->")
    cell = text.index(" ± ", start)
    copy = tmp_path / "README.md"
    # the figure's link is relative to the page: place the (not drawn) figure as it is beside the README
    figure = tmp_path / "eval" / "recipe-paper" / "seed3" / "readme_food_vs_team.png"
    check = [sys.executable, str(root / "scripts" / "readme_results.py"), "--figure", str(figure), "--check", str(copy)]
    copy.write_text(text)
    assert subprocess.run(check, capture_output=True, text=True, timeout=120).returncode == 0
    copy.write_text(text[:cell] + "0" + text[cell:])
    done = subprocess.run(check, capture_output=True, text=True, timeout=120)
    assert done.returncode == 1
    assert f"run scripts/readme_results.py --write {copy}" in done.stderr


def test_readme_paired_table_has_the_trail_variants_where_they_were_run():
    """The README's paired block (scripts/readme_results.py) gives each out-of-distribution trail
    variant that was evaluated a row, paired with standard trails on the same scenarios."""
    import importlib.util
    from pathlib import Path

    path = Path(__file__).resolve().parents[1] / "scripts" / "readme_results.py"
    spec = importlib.util.spec_from_file_location("readme_results", path)
    readme_results = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(readme_results)

    def paper(algorithm, food, seed, variant=""):
        return {**record(algorithm, food, seed, agents=16), "variant": variant, "size": 128, "steps": 1024}

    model = ([paper("formic", f, s) for f, s in ((100, 1), (200, 2))]
             + [paper("formic", f, s, "trails-flat") for f, s in ((90, 1), (170, 2))])
    baselines = [paper("csaf11", 50, s) for s in (1, 2)]
    lines = readme_results.paired_table(model, baselines)
    flat = next(line for line in lines if "trails without gradient" in line)
    # differences -10 and -30: mean -20 of a 150 mean, 13% less; t(0.975, 1) * std(ddof=1) / sqrt(2) = 127.06
    assert flat.startswith("|  | trails without gradient: less food | 13% [-71, 98] (n=2) | – |")
    assert not any("noisy" in line or "random concentration" in line for line in lines)  # not run: no row


def test_readme_small_worlds_table_gives_food_per_cell_and_pairs_formic_with_each_rival():
    """scripts/readme_results.py: in the 32x32 and 64x64 worlds, food per cell (with the ratio
    to the planner) and ForMIC minus each rival paired per scenario; no section before the model
    has played them."""
    import importlib.util
    from pathlib import Path

    path = Path(__file__).resolve().parents[1] / "scripts" / "readme_results.py"
    spec = importlib.util.spec_from_file_location("readme_results", path)
    readme_results = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(readme_results)

    def small(algorithm, food, seed, size=32):
        return {**record(algorithm, food, seed, agents=32), "size": size, "steps": 1024, "scenario": f"s{seed}",
                "food_curve": [0.0, food], "step_ms_mean": 1.0, "world_step_ms_mean": 1.0}

    model = [small("formic", f, s) for f, s in ((100, 1), (140, 2), (120, 3))]
    baselines = ([small("csaf11", f, s) for f, s in ((80, 1), (90, 2), (100, 3))]
                 + [small("planner", 200, s) for s in (1, 2, 3)] + [small("csaf11", 500, 1, size=64)])
    assert readme_results.small_world_tables([], baselines) == []
    lines = readme_results.small_world_tables(model, baselines)
    assert "| 32x32 (n=3) | **ForMIC** | – | 120 ± 20 [0.60] | – | – |" in lines
    assert "|  | C-SAF-11 | – | 90 ± 10 [0.45] | – | – |" in lines
    # differences 20, 50, 20: mean 30, std 17.32; t(0.975, 2) = 4.303 -> half-width 43.0
    assert "| 32x32 | ForMIC − C-SAF-11 (food) | – | +30 [-13, +73] (n=3) | – | – |" in lines
    assert not any(line.startswith("| 64x64") for line in lines)  # ForMIC has not played it
