#!/usr/bin/env python3
"""The ROS transports against one process and against the publish floor, side by side
(docs/ros.md, "Speed").

Each round runs, on one scenario and seed: ``formic sim``, ``formic run --transport batched`` and
``formic run --transport per-agent`` (steps/s after step 0 by the wall clock, as their summaries
say: everything a step does, start-up and the first step's warm-up excluded) and
``benchmarks/rclpy_publish.py`` (the cost of one rclpy publish to another process, measured in
the same run, of an ``AgentAction`` and of the world's serialized 3.9 kB ``AgentObservation``),
every other round in reverse order. The serial publish floor of the per-agent transport is
``formic sim``'s step plus two publishes an agent, one after the other: two small ones
(``floor``, as the target was set) and, beside it, the messages the transport sends (one
observation and one action an agent: ``message floor``), and those messages with the reader's CPU
time to take each (``with takes``: a bound from the other side, as if nothing overlapped).
Printed: medians over the rounds, the ratios (each the median of the rounds' own ratios: a busy
machine's speed drifts from round to round, and the paths of one round run minutes apart at
most), where a step's time went in each transport (``formic run --timeline``'s segments), and
whether food and state digest equal ``formic sim``'s in every run:

    .venv/bin/python benchmarks/transport_floor.py --agents 16 --size 32 --steps 64 --rounds 1
"""

from __future__ import annotations

import argparse
import json
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
FORMIC = [sys.executable, "-m", "formic_cli.main"]


def run_json(command: list[str]) -> dict:
    """The last line of a command's stdout, as JSON (the command must succeed)."""
    done = subprocess.run(command, cwd=ROOT, capture_output=True, text=True, check=False)
    if done.returncode != 0:
        raise SystemExit(f"{' '.join(command)} failed ({done.returncode}): {done.stderr[-2000:]}")
    return json.loads(done.stdout.strip().splitlines()[-1])


def one_round(world: list[str], agents: int, domain_id: int, out: Path, reverse: bool) -> dict:
    """One measurement of every path (steps/s, or µs a publish) with each run's food and digest,
    in ``reverse`` order every other round (a drifting machine then favours no path)."""
    row: dict = {}

    def sim() -> None:
        done = run_json([*FORMIC, "sim", *world, "--json", "--out", str(out)])
        row["sim"] = (done["steps_per_s"], done["food"], done["state_digest"])

    def run(transport: str) -> None:
        with tempfile.TemporaryDirectory() as timeline:  # where the step's time goes (formic run --timeline)
            done = run_json([*FORMIC, "run", *world, "--transport", transport, "--domain-id", str(domain_id),
                             "--timeline", f"{timeline}/marks", "--json"])
        row[transport] = (done["steps_per_s"], done["food"], done["state_digest"])
        row[f"{transport} segments"] = done["timeline"]["segments_ms"]

    def publish(message: str) -> None:
        done = run_json([sys.executable, str(ROOT / "benchmarks" / "rclpy_publish.py"), "--topics", str(agents),
                         "--rounds", "100", "--message", message, "--domain-id", str(domain_id), "--json"])
        row[f"us_per_{message}"], row[f"us_per_{message}_take"] = done["us_per_publish"], done["us_per_take"]

    jobs = [sim, lambda: run("batched"), lambda: run("per-agent"), lambda: publish("action"),
            lambda: publish("observation")]
    for job in reversed(jobs) if reverse else jobs:
        job()
    return row


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--agents", type=int, default=128)
    parser.add_argument("--size", type=int, default=128)
    parser.add_argument("--steps", type=int, default=1024)
    parser.add_argument("--seed", type=int, default=1)
    parser.add_argument("--policy", default="formic")
    parser.add_argument("--rounds", type=int, default=4,
                        help="Medians over this many rounds (every other one in reverse order).")
    parser.add_argument("--domain-id", type=int, default=78, help="A ROS domain no other run uses.")
    parser.add_argument("--out", type=Path, default=Path("out/transport_floor"), help="formic sim's picture.")
    args = parser.parse_args()

    world = ["--agents", str(args.agents), "--size", str(args.size), "--steps", str(args.steps),
             "--seed", str(args.seed), "--policy", args.policy]
    rounds = [one_round(world, args.agents, args.domain_id, args.out, reverse=i % 2 == 1) for i in range(args.rounds)]
    for r in rounds:  # serial: sim's step, then 2N publishes
        r["floor"] = (1.0 / (1.0 / r["sim"][0] + 2 * args.agents * r["us_per_action"] * 1e-6),)
        r["message floor"] = (1.0 / (1.0 / r["sim"][0] + args.agents * (r["us_per_action"] + r["us_per_observation"])
                                     * 1e-6),)
        r["with takes"] = (1.0 / (1.0 / r["sim"][0] + args.agents * 1e-6 * sum(
            r[f"us_per_{m}{part}"] for m in ("action", "observation") for part in ("", "_take"))),)
    paths = ("sim", "floor", "message floor", "with takes", "batched", "per-agent")
    median = {key: statistics.median(r[key][0] for r in rounds) for key in paths}
    action_us, observation_us, take_us = (statistics.median(r[key] for r in rounds) for key in (
        "us_per_action", "us_per_observation", "us_per_observation_take"))

    def ratio(over: str, key: str) -> float:
        return statistics.median(r[over][0] / r[key][0] for r in rounds)

    expected = rounds[0]["sim"][1:]
    same = all(r[key][1:] == expected for r in rounds for key in ("sim", "batched", "per-agent"))

    print(f"{args.agents} agents, {args.size}x{args.size}, {args.steps} steps, seed {args.seed}, "
          f"policy {args.policy}; medians of {args.rounds} round(s)")
    print(f"publish ({args.agents} topics): {action_us:.1f} us an action, {observation_us:.1f} us an observation "
          f"(taking one: {take_us:.1f} us); "
          f"per-agent serial floor {median['floor']:.0f} steps/s ({ratio('sim', 'floor'):.2f}x formic sim), "
          f"with its own messages {median['message floor']:.0f} ({ratio('sim', 'message floor'):.2f}x)")
    print(f"{'path':<22}{'steps/s':>9}{'vs sim':>9}{'vs floor':>10}{'vs msg floor':>14}   rounds")
    for key, label in (("sim", "formic sim"), ("floor", "floor (2 actions)"), ("message floor", "floor (obs + action)"),
                       ("with takes", "floor with takes"), ("batched", "run batched"), ("per-agent", "run per-agent")):
        each = " ".join(f"{r[key][0]:.0f}" for r in rounds)
        ratios = f"{ratio('sim', key):>8.2f}x{ratio('floor', key):>9.2f}x{ratio('message floor', key):>13.2f}x"
        print(f"{label:<22}{median[key]:>9.0f}{ratios}   {each}")
    print("where a step's time went (ms, medians over the rounds of each segment's median; formic run --timeline):")
    print(f"{'segment':<66}{'batched':>9}{'per-agent':>11}")
    for segment in rounds[0]["batched segments"]:
        cells = (statistics.median(r[f"{t} segments"][segment] for r in rounds) for t in ("batched", "per-agent"))
        print(f"{segment:<66}" + "".join(f"{ms:>{w}.3f}" for ms, w in zip(cells, (9, 11))))
    print(f"food {expected[0]}, digest {expected[1]}: "
          + ("equal in every run" if same else "DIFFERENT: " + json.dumps(rounds)))
    if not same:
        raise SystemExit(1)


if __name__ == "__main__":
    main()
