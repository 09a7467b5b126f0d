#!/usr/bin/env python3
"""Before/after speed of two revisions: `formic bench world`, `bench ros` and `bench policy` at
128 agents, and training on the paper recipe's workload (benchmarks/training_speed.py), run in
turn (before, after, before, ...) so that a drifting machine hits both alike, and the median of
each figure with the after/before ratio. Run it on a quiet machine.

    .venv/bin/python benchmarks/compare_revisions.py 2fc1868 --rounds 3

The "before" revision is checked out into a temporary git worktree and run with this checkout's
virtual environment (its ``src/`` first on ``PYTHONPATH``); "after" is this working tree.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
BENCHES = {  # name: (formic arguments, {figure: path into the JSON})
    "world": (["bench", "world", "--teams", "128", "--json"], {"steps/s": ("results", 0, "steps_per_s")}),
    "ros": (["bench", "ros", "--agents", "128", "--json"], {
        "batched steps/s": ("results", 0, "steps_per_s"), "per-agent steps/s": ("results", 1, "steps_per_s")}),
    "policy": (["bench", "policy", "--batch", "128", "--json"], {
        "inference agent-steps/s": ("inference_agent_steps_per_s",),
        "training agent-steps/s": ("training_agent_steps_per_s",)}),
    # the paper recipe's workload (benchmarks/training_speed.py, this tree's recipe for both sides)
    "training": ([str(ROOT / "benchmarks" / "training_speed.py"), "--threads", "2", "--json"], {
        "recipe training agent-steps/s": ("agent_steps_per_s",)}),
}


def run_bench(src: Path, args: list[str], dds_profile: str | None) -> dict:
    env = {**os.environ, "PYTHONPATH": str(src)}
    if dds_profile:
        env["FASTRTPS_DEFAULT_PROFILES_FILE"] = dds_profile
    if args[0].endswith(".py"):  # a benchmark script of this tree, timing ``src`` (its --src)
        command = [sys.executable, *args, "--src", str(src)]
        env["PYTHONPATH"] = str(ROOT / "src")
    else:
        command = [sys.executable, "-m", "formic_cli.main", *args]
    done = subprocess.run(command, env=env, capture_output=True, text=True, timeout=900, check=True)
    return json.loads([line for line in done.stdout.splitlines() if line.startswith("{")][-1])


def pick(result: dict, path: tuple) -> float:
    for key in path:
        result = result[key]
    return float(result)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("before", help="git revision to compare this working tree with")
    parser.add_argument("--rounds", type=int, default=3)
    parser.add_argument("--benches", default=",".join(BENCHES))
    parser.add_argument("--dds-profile", help="Fast DDS XML profile for both sides (e.g. this tree's "
                        "src/formic_ros/fastdds/loopback.xml: tells code from transport settings)")
    args = parser.parse_args()
    figures: dict[tuple[str, str], dict[str, list[float]]] = {}
    with tempfile.TemporaryDirectory(prefix="formic-before-") as tmp:
        worktree = Path(tmp) / "before"
        subprocess.run(["git", "-C", str(ROOT), "worktree", "add", "--detach", str(worktree), args.before],
                       check=True, capture_output=True)
        try:
            for round_ in range(args.rounds):
                for name in args.benches.split(","):
                    command, wanted = BENCHES[name]
                    for side, src in (("before", worktree / "src"), ("after", ROOT / "src")):
                        result = run_bench(src, command, args.dds_profile)
                        for figure, path in wanted.items():
                            figures.setdefault((name, figure), {}).setdefault(side, []).append(pick(result, path))
                print(f"round {round_ + 1}/{args.rounds} done", file=sys.stderr, flush=True)
        finally:
            subprocess.run(["git", "-C", str(ROOT), "worktree", "remove", "--force", str(worktree)], check=False)
    profile = f", DDS profile {Path(args.dds_profile).name} on both" if args.dds_profile else ""
    print(f"| bench (128 agents{profile}) | before ({args.before}) | after | after/before |\n|---|---|---|---|")
    for (name, figure), sides in figures.items():
        before, after = statistics.median(sides["before"]), statistics.median(sides["after"])
        print(f"| {name}: {figure} | {before:,.0f} | {after:,.0f} | {after / before:.3f} |")


if __name__ == "__main__":
    main()
