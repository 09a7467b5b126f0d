"""Do loaded agents find the nest? Trips, and loads never delivered, per model (issue 26).

Without pheromones an agent's only cue to the nest is its memory of its own moves (SPEC §3).
This counts, over every step of the first stored scenarios per team size: completed loaded
trips (from the step an agent's load first rises above 0 to the step it reaches 0 again, queues
included) and completed empty trips (the reverse), deliveries per agent, the share of
agent-steps spent carrying, and the share spent in a load never delivered: from an agent's last
pickup (or step 0) to the episode's end, while it still carries. Completed trips alone hide
the agents that never come back: they end only when a trip was short.

    .venv/bin/python analysis/homing.py --model models/training/tables/no-pheromones/model.pt \
        --channel-empty --scenarios eval/tables/reference/scenarios --teams 16,128 --count 3
"""

from __future__ import annotations

import json
from pathlib import Path

import click
import numpy as np

from formic_cli.options import probe_options, stored_teams
from formic_eval.probes import probe_rows
from formic_runtime.threads import configure_threads


class TripCounter:
    """Loaded and empty trips, deliveries and unfinished loads; call after every step (the
    state before the first comes from the world's scenario)."""

    def __init__(self) -> None:
        self.loaded_trips: list[int] = []
        self.empty_trips: list[int] = []
        self.carrying: np.ndarray | None = None
        self.since: np.ndarray | None = None  # the step the agent's current state began
        self.seen_start: np.ndarray | None = None  # whether that step was seen (not the episode's start)
        self.deliveries: np.ndarray | None = None
        self.carrying_steps = 0
        self.t = 0

    def __call__(self, world) -> None:
        carrying, t = world.carrying.copy(), int(world.t)
        if self.carrying is None:  # step 0: as the scenario placed them
            self.carrying = np.array([start.loaded for start in world.scenario.agents])
            self.since = np.zeros(len(carrying), int)
            self.seen_start, self.deliveries = np.zeros(len(carrying), bool), np.zeros(len(carrying), int)
        for a in np.flatnonzero(carrying != self.carrying):
            if self.seen_start[a]:
                (self.loaded_trips if self.carrying[a] else self.empty_trips).append(t - int(self.since[a]))
            self.deliveries[a] += int(self.carrying[a])
            self.since[a], self.seen_start[a] = t, True
        self.carrying_steps += int(carrying.sum())
        self.carrying, self.t = carrying, t

    def table(self) -> dict[str, float]:
        agent_steps = max(len(self.carrying) * self.t, 1)
        undelivered = np.where(self.carrying, self.t - self.since, 0).sum()
        return {"deliveries_per_agent": float(self.deliveries.mean()),
                "loaded_trip": float(np.mean(self.loaded_trips)) if self.loaded_trips else float("nan"),
                "empty_trip": float(np.mean(self.empty_trips)) if self.empty_trips else float("nan"),
                "carrying": self.carrying_steps / agent_steps,
                "undelivered": float(undelivered) / agent_steps}


@click.command()
@probe_options(policies="formic", teams="16,128")
@click.option("--steps", default=1024, show_default=True)
@click.option("--out", type=click.Path(dir_okay=False), help="Also write the table here as JSON.")
def main(policies, model, scenario_dir, size, teams, count, channel_empty, steps, out) -> None:
    """Per model and team size: deliveries, trip lengths and loads never delivered."""
    configure_threads()
    results = []
    for row in probe_rows(stored_teams(scenario_dir, size, teams, count), policies, model, steps, TripCounter,
                          channel_empty):
        results.append(row)
        click.echo(f"{row['policy']:8s} {row['agents']:4d} agents  food {row['food']:6.1f}  deliveries/agent "
                   f"{row['deliveries_per_agent']:4.1f}  trips: loaded {row['loaded_trip']:5.1f}, empty "
                   f"{row['empty_trip']:5.1f} steps  carrying {row['carrying']:.0%}  "
                   f"in a load never delivered {row['undelivered']:.0%}")
    if out:
        Path(out).write_text(json.dumps({"steps": steps, "model": model, "channel_empty": channel_empty,
                                         "results": results}, indent=1))


if __name__ == "__main__":
    main()
