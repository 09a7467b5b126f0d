#!/usr/bin/env python3
"""The README's benchmark table, measured by one command on this machine (run it quiet):

    .venv/bin/python benchmarks/readme_table.py

Each row is a `formic` command (or benchmarks/training_speed.py) run as a user would run it, at
128 agents where the figure depends on the team: the core, the network's inference, training
end to end on the paper recipe's workload, ROS lockstep on both transports, and a 1024-step
episode of the shipped model in one process and over ROS (wall clock of the whole command,
start-up included). Prints a markdown table.
"""

from __future__ import annotations

import argparse
import json
import platform
import subprocess
import sys
import time
from datetime import date
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
EPISODE = ["--agents", "128", "--size", "128", "--steps", "1024", "--seed", "1", "--policy", "formic", "--json"]


def run(args: list[str]) -> tuple[dict, float]:
    """The last JSON line a command prints, and its wall clock."""
    started = time.perf_counter()
    done = subprocess.run([sys.executable, *args], capture_output=True, text=True, timeout=900, check=True, cwd=ROOT)
    wall = time.perf_counter() - started
    return json.loads([line for line in done.stdout.splitlines() if line.startswith("{")][-1]), wall


def formic(*args: str) -> tuple[dict, float]:
    return run(["-m", "formic_cli.main", *args])


def main() -> None:
    rows = []
    world, _ = formic("bench", "world", "--json")
    rows.append(("core, 128x128, random valid actions, observations included", "`formic bench world`",
                 " / ".join(f"{r['steps_per_s']:,.0f}" for r in world["results"])
                 + " steps/s with 16 / 32 / 64 / 128 agents"))
    policy, _ = formic("bench", "policy", "--network", "cpu-feedback", "--json")
    rows.append(("inference, `cpu-feedback` net, batch 128, 2 threads", "`formic bench policy --network cpu-feedback`",
                 f"{policy['inference_agent_steps_per_s']:,.0f} agent-steps/s"))
    for threads in (1, 2):
        training, _ = run([str(ROOT / "benchmarks" / "training_speed.py"), "--threads", str(threads), "--json"])
        rows.append((f"training end to end, the paper recipe's last stage (352 agents, 64 learning), "
                     f"{threads} thread(s)",
                     f"`benchmarks/training_speed.py --threads {threads}`",
                     f"{training['agent_steps_per_s']:,.0f} agent-steps/s"))
    ros, _ = formic("bench", "ros", "--agents", "128", "--json")
    for result in ros["results"]:
        rows.append((f"ROS lockstep, 128 agents on 64x64, {result['transport']}, random policy",
                     "`formic bench ros --agents 128`", f"{result['steps_per_s']:,.0f} steps/s"))
    sim, sim_wall = formic("sim", *EPISODE)
    rows.append(("1024-step episode of the shipped model, 128 agents, one process",
                 "`formic sim " + " ".join(EPISODE[:-1]) + "`",
                 f"{sim_wall:.1f} s, food {sim['food']:g}"))
    for transport in ("batched", "per-agent"):
        result, wall = formic("run", *EPISODE, "--transport", transport)
        rows.append((f"the same episode over ROS, {transport}", f"`formic run ... --transport {transport}`",
                     f"{wall:.1f} s ({result['steps_per_s']:.0f} steps/s), food {result['food']:g}"))
    print(f"Measured {date.today()} on {platform.machine()}, {platform.processor() or 'CPU'}, quiet:\n")
    print("| what | command | result |\n|---|---|---|")
    for what, command, result in rows:
        print(f"| {what} | {command} | {result} |")


if __name__ == "__main__":
    argparse.ArgumentParser(description=__doc__.splitlines()[0]).parse_args()  # --help, and no stray arguments
    main()
