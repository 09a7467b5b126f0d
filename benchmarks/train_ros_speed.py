#!/usr/bin/env python3
"""`formic train-ros` against `formic train` on the same settings: the whole command, and the
steady state once every process has started.

Both train the cpu preset from fresh weights on one world of N agents, all learning (train-ros
drives that world with one learning host), for E episodes of 512 steps. Per team size:

- whole: each command's wall clock, process start, imports and DDS discovery included;
- steady: agent-steps per second from the first step to the last update. `formic train`
  prints this itself (its clock runs per episode set, after start-up); for `formic train-ros`
  it is read off the nodes' log lines (`--log-dir`): the world's first "stepping" line and the
  trainer's last "update" line (all three processes run on this machine, one clock).

Rounds alternate the two commands; the median is printed. Run it on a quiet machine (pause
background training):

    .venv/bin/python benchmarks/train_ros_speed.py --teams 16 --episodes 2 --rounds 1
"""

from __future__ import annotations

import argparse
import json
import re
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
FORMIC = [sys.executable, "-m", "formic_cli.main"]
STAMP = re.compile(r"^\[\w+\] \[(\d+\.\d+)\] \[([\w.]+)\]: (.*)$")


def run(args: list[str]) -> tuple[float, str]:
    started = time.monotonic()
    done = subprocess.run(FORMIC + args, cwd=ROOT, capture_output=True, text=True, check=True)
    return time.monotonic() - started, done.stdout + done.stderr


def in_process(teams: int, episodes: int, work: Path) -> dict:
    seconds, output = run(["train", "--preset", "cpu", "--set", f"teams={teams}", "--episodes", str(episodes),
                           "--fresh", "--run-dir", str(work / "train")])
    rates = re.findall(r"\| ([\d,]+) agent-steps/s \|", output)
    return {"whole_s": seconds, "steady_agent_steps_per_s": float(rates[-1].replace(",", ""))}


def over_ros(teams: int, episodes: int, work: Path) -> dict:
    logs = work / "logs"
    seconds, _ = run(["train-ros", "--preset", "cpu", "--set", f"teams={teams}", "--episodes", str(episodes),
                      "--fresh", "--run-dir", str(work / "train-ros"), "--log-dir", str(logs)])
    first_step = last_update = None
    for name in ("world", "trainer"):
        for line in (logs / f"{name}.log").read_text().splitlines():
            match = STAMP.match(line)
            if match is None:
                continue
            stamp, text = float(match[1]), match[3]
            if name == "world" and text.startswith("stepping:") and first_step is None:
                first_step = stamp
            elif name == "trainer" and text.startswith("update "):
                last_update = stamp
    if first_step is None or last_update is None:
        raise RuntimeError(f"no stepping or update line in {logs}")
    from formic_trainer.config import make_config

    steady = teams * make_config("cpu").episode_steps * episodes / (last_update - first_step)
    return {"whole_s": seconds, "steady_agent_steps_per_s": steady}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--teams", default="16,64", help="Team sizes (one world each), comma list.")
    parser.add_argument("--episodes", type=int, default=3)
    parser.add_argument("--rounds", type=int, default=1, help="Alternating rounds; the median is printed.")
    parser.add_argument("--json", action="store_true", help="Print one JSON object.")
    args = parser.parse_args()
    rows = []
    for teams in (int(n) for n in args.teams.split(",")):
        measured: dict[str, list[dict]] = {"train": [], "train-ros": []}
        for _ in range(args.rounds):
            for name, measure in (("train", in_process), ("train-ros", over_ros)):
                with tempfile.TemporaryDirectory(prefix="formic-bench-") as work:
                    measured[name].append(measure(teams, args.episodes, Path(work)))
        row = {"teams": teams, "episodes": args.episodes}
        for name, results in measured.items():
            for key in ("whole_s", "steady_agent_steps_per_s"):
                row[f"{name}:{key}"] = statistics.median(r[key] for r in results)
        row["whole_ratio"] = row["train:whole_s"] / row["train-ros:whole_s"]
        row["steady_ratio"] = row["train-ros:steady_agent_steps_per_s"] / row["train:steady_agent_steps_per_s"]
        rows.append(row)
        if not args.json:
            ros, one = row["train-ros:steady_agent_steps_per_s"], row["train:steady_agent_steps_per_s"]
            print(f"{teams:4d} agents, {args.episodes} episodes: whole command {row['train-ros:whole_s']:.1f} s "
                  f"over ROS against {row['train:whole_s']:.1f} s ({row['whole_ratio']:.2f}x); steady "
                  f"{ros:,.0f} against {one:,.0f} agent-steps/s ({row['steady_ratio']:.2f}x)", flush=True)
    if args.json:
        print(json.dumps({"rounds": args.rounds, "results": rows}))


if __name__ == "__main__":
    main()
