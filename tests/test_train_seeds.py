"""scripts/train_seeds.sh: a recipe's seeds trained, trimmed and sent to their test episodes one
after another; a seed another process holds is left to it; a rerun finds a finished seed finished."""

from __future__ import annotations

import gzip
import json
import os
import subprocess
import sys
from pathlib import Path

from formic_world.files import held_directory

ROOT = Path(__file__).resolve().parents[1]

# the real CLI for training; an evaluation is only recorded (hours of test episodes otherwise)
RECORDER = """#!/bin/sh
printf '%s\\n' "$*" >> "$CALLS"
[ "$1" = eval ] && exit "${EVAL_STATUS:-0}"
exec "$PYTHON" -m formic_cli.main "$@"
"""


def test_seeds_are_trained_trimmed_and_evaluated_and_a_held_seed_is_skipped(tmp_path):
    recorder = tmp_path / "formic"
    recorder.write_text(RECORDER)
    recorder.chmod(0o755)
    runs, evals, calls = tmp_path / "runs", tmp_path / "evals", tmp_path / "calls"
    env = {**os.environ, "FORMIC": str(recorder), "CALLS": str(calls), "PYTHON": sys.executable}

    def seeds(which: str, **extra: str) -> subprocess.CompletedProcess:
        return subprocess.run([str(ROOT / "scripts" / "train_seeds.sh"), "smoke", which, str(runs), str(evals)],
                              capture_output=True, text=True, timeout=300, env={**env, **extra}, cwd=tmp_path)

    with held_directory(runs / "seed2"):  # another process trains seed 2
        done = seeds("1-2")
    assert done.returncode == 0, done.stderr
    lines = done.stdout.splitlines()
    assert lines[0] == f"seed 1: training ({runs}/seed1.log)"
    assert lines[-2:] == [f"seed 1: test episodes on Fig. 5's cells ({evals}/seed1)",
                          "seed 2: another process is training it, skipped"]
    assert lines[-3].startswith(f"{runs}/seed1: ") and lines[-3].endswith(" bytes")  # lean_run's last line
    assert sorted(p.name for p in (runs / "seed1").glob("**/*.pt")) == ["model.pt"]  # trimmed
    assert not (runs / "seed2" / "recipe.json").exists()
    evaluations = [line for line in calls.read_text().splitlines() if line.startswith("eval")]
    assert evaluations == [f"eval --algorithms formic --model {runs}/seed1/model.pt --seed 7 --steps 1024 --out "
                           f"{evals}/seed1 --sizes 128 --teams 16,32,64,128 --obstacles 0,0.05 --env "
                           "infinite,finite,wipeout --scenarios 20 --workers 1",
                           f"eval --out {evals}/seed1 --report"]
    with held_directory(runs / "seed1"):  # finished, but another process holds it (trimming it)
        skipped = seeds("1")
    assert skipped.returncode == 0 and skipped.stdout.splitlines()[-1] == \
        "seed 1: another process is training it, skipped", skipped.stdout
    with held_directory(evals / "seed1"):  # another process is playing its test episodes
        waits = seeds("1")
    assert waits.returncode == 0 and waits.stdout.splitlines()[-1] == \
        "seed 1: another process is evaluating it, skipped", waits.stdout
    again = seeds("1")
    assert again.returncode == 0, again.stderr
    assert (runs / "seed1.log").read_text().splitlines()[-1].endswith("the run is finished")
    assert sorted(p.name for p in (runs / "seed1").glob("**/*.pt")) == ["model.pt"]
    # a stopped command (Ctrl-C: 130, here the evaluation) stops the script with the line that goes on
    stopped = seeds("1-2", EVAL_STATUS="130")
    assert (stopped.returncode, stopped.stderr) == (
        130, f"seed 1: stopped (see {runs}/seed1.log): rerun the same command to go on\n"), stopped.stderr
    assert not (runs / "seed2" / "recipe.json").exists()  # seed 2 never started
    # trained and tested (its evaluation sealed): passed over, its log untouched
    with gzip.open(evals / "seed1" / "episodes.jsonl.gz", "wt") as sealed:
        sealed.write("{}\n" * 3)
    log = (runs / "seed1.log").read_text()
    tested = seeds("1")
    assert (tested.returncode, tested.stdout) == (0, f"seed 1: trained and tested ({evals}/seed1), skipped\n")
    assert (runs / "seed1.log").read_text() == log
    # --status: a line a seed, nothing run
    (evals / "seed2").mkdir()
    (evals / "seed2" / "episodes.jsonl").write_text("{}\n" * 2)
    selection = json.loads((runs / "seed1" / "selection.json").read_text())
    chosen = selection["chosen"]
    with held_directory(runs / "seed2"):
        status = subprocess.run([str(ROOT / "scripts" / "train_seeds.sh"), "--status", "smoke", "1-2", str(runs),
                                 str(evals)], capture_output=True, text=True, timeout=120, env=env, cwd=tmp_path)
    assert status.returncode == 0, status.stderr
    first, second = status.stdout.splitlines()
    assert first.startswith(f"seed 1: finished: model.pt = {chosen} (validation food "
                            f"{selection['candidates'][chosen]['food_mean']:.1f}); ")
    assert first.endswith(" CPU-h spent | test: 3 episodes, sealed")
    assert second == "seed 2: not started (training now) | test: 2 episodes so far"
    assert (runs / "seed1.log").read_text() == log and not (runs / "seed2" / "recipe.json").exists()
