"""Do agents follow the pheromone trails? Moves along the local gradient, per policy.

Evidence of implicit communication beyond the ablation (models/README.md, issue 11). A trail
is laid by carrying agents walking from a resource towards the nest: its concentration is
highest at the resource end (SPEC §2), so a loaded agent that reads it should move *down* the
gradient and an empty agent looking for food *up*. For every step of every stored scenario,
each agent that was free and moved (not into a queue) from a cell whose pheromone, as it
observed it, was at least ``--threshold`` is counted by how the pheromone of the cell it
moved to compares with its own: up, down (still on the trail), off the trail (below the
threshold) or level. A carrying agent deposits on the cell it
stood on when it acts (SPEC §1), so its own fresh trail never counts as the cell it stands on.
C-SAF-11 never reads the ForMIC pheromone (its homing shows what the geometry alone gives) and
random walkers give the floor.

    git show 57b96f9:models/training/paper-ref/latest.pt > /tmp/paper-ref.pt  # in the history only
    .venv/bin/python analysis/trail_following.py --model /tmp/paper-ref.pt \
        --teams 32,64 --count 4 --out models/trail_following.json
"""

from __future__ import annotations

import json
from pathlib import Path

import click
import numpy as np

from formic_cli.options import probe_options, stored_teams
from formic_eval.probes import play
from formic_runtime.threads import configure_threads

KINDS = ("up", "down", "off", "level")


class TrailCounter:
    """Counts, per load state, moves up / down / level along the pheromone the agent saw."""

    def __init__(self, threshold: float):
        self.threshold = threshold
        self.counts = {load: dict.fromkeys(KINDS, 0) for load in ("loaded", "empty")}
        self.free_moves = {"loaded": 0, "empty": 0}
        self.before: tuple[np.ndarray, ...] | None = None

    def start(self, world) -> None:
        self.before = (world.pos.copy(), world.carrying.copy(), world.queued.copy(), world.visible_pheromone().copy())

    def __call__(self, world) -> None:
        """After each step (the first step only sets the state the next one is compared with)."""
        if self.before is None:
            self.start(world)
            return
        pos, carrying, queued, seen = self.before
        moved = (world.pos != pos).any(axis=1) & ~queued & ~world.queued
        rows, cols = pos[:, 0], pos[:, 1]
        here = seen[rows, cols]
        there = seen[world.pos[:, 0], world.pos[:, 1]]
        on_trail = moved & (here >= self.threshold)
        for load, mask in (("loaded", carrying), ("empty", ~carrying)):
            self.free_moves[load] += int((moved & mask).sum())
            sel = on_trail & mask
            stays = there >= self.threshold
            self.counts[load]["up"] += int((sel & (there > here)).sum())
            self.counts[load]["down"] += int((sel & stays & (there < here)).sum())
            self.counts[load]["off"] += int((sel & ~stays).sum())
            self.counts[load]["level"] += int((sel & stays & (there == here)).sum())
        self.start(world)

    def table(self) -> dict:
        out = {}
        for load, counts in self.counts.items():
            total = sum(counts.values())
            out[load] = {
                "moves_on_trail": total,
                "share_of_moves_on_trail": total / max(self.free_moves[load], 1),
                **{f"share_{kind}": counts[kind] / max(total, 1) for kind in KINDS},
            }
        return out


@click.command()
@probe_options(policies="formic,csaf11,random", teams="32,64")
@click.option("--steps", type=int, help="Steps per episode (default: the scenario's).")
@click.option("--threshold", default=0.05, show_default=True, help="Pheromone that makes a cell part of a trail.")
@click.option("--out", type=click.Path(dir_okay=False), help="Also write the table here as JSON.")
def main(policies, model, scenario_dir, size, teams, count, channel_empty, steps, threshold, out) -> None:
    """Share of moves up / down the pheromone gradient on trails, loaded and empty agents."""
    configure_threads()
    results = []
    for team, scenarios in stored_teams(scenario_dir, size, teams, count):
        for policy in policies.split(","):
            counter = TrailCounter(threshold)
            food = []
            for scenario in scenarios:
                counter.before = None
                episode = play(scenario, policy, model, steps, counter, channel_empty)
                food.append(episode.food)
            row = {"policy": policy, "agents": team, "scenarios": len(scenarios), "food": float(np.mean(food)),
                   **counter.table()}
            results.append(row)
            click.echo(f"{policy:8s} {team:4d} agents  food {row['food']:6.1f}  " + "  ".join(
                f"{load}: {row[load]['share_of_moves_on_trail']:.0%} of moves on trail, "
                f"up {row[load]['share_up']:.0%} down {row[load]['share_down']:.0%} off {row[load]['share_off']:.0%}"
                for load in ("loaded", "empty")))
    if out:
        Path(out).write_text(json.dumps({"threshold": threshold, "model": model, "results": results}, indent=1))


if __name__ == "__main__":
    main()
