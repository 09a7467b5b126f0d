"""Where do carrying agents wait? Crowding at the nest, per policy (issue 11's 128-agent gap).

The nest serves at most 4 agents at once; an agent that has unloaded stays on its dock (spot
0) until it walks away (SPEC §1). For every step of every stored scenario this averages: the
carrying agents that are free (not queued) within ``--radius`` cells (Chebyshev) of the nest
centre, the agents in cache queues, the docks held by an agent that has finished (free, on
spot 0), of the crowd's agents the share whose action moved them, and how often a free agent that
could JOIN (valid at the start of a step: a loaded agent a cache queue, an empty one a resource
queue) stands in such a queue after the step. A policy that homes
by dead reckoning and pheromones can reach the nest's neighbourhood and still miss the queue
entries in a crowd; one that knows the nest direction (C-SAF-11) queues instead.

    .venv/bin/python analysis/nest_crowding.py --model models/formic_paper.pt --teams 64,128 --count 4
"""

from __future__ import annotations

import json
from pathlib import Path

import click
import numpy as np

from formic_cli.options import probe_options, stored_teams
from formic_eval.probes import probe_rows
from formic_runtime.threads import configure_threads
from formic_world.geometry import nest_centre

MEASURES = ("crowd", "in_cache_queues", "docks_held", "crowd_moving", "cache_join", "resource_join")
SHARES = {"crowd_moving": "crowd", "cache_join": "could_join_cache", "resource_join": "could_join_resource"}


class CrowdCounter:
    """Per-step sums of the crowding measures; call after every step."""

    def __init__(self, radius: int):
        self.radius = radius
        self.sums = dict.fromkeys(MEASURES, 0.0)
        self.steps = 0
        self.denominators = dict.fromkeys(SHARES.values(), 0)
        self.before: tuple[np.ndarray, ...] | None = None

    def __call__(self, world) -> None:
        centre = np.array(nest_centre(*world.grid.shape))  # between the 4 caches
        near = np.abs(world.pos - centre).max(axis=1) <= self.radius
        crowd = near & world.carrying & ~world.queued
        cache_queued = world.queued & (world.queue_of < 4)
        docks = world.queue_cells[:4, 0]
        on_dock = world.agent_at[docks[:, 0], docks[:, 1]]
        held = [a for a in on_dock if a >= 0 and not world.queued[a]]
        if self.before is not None:
            was_crowd, pos, could_join_cache, could_join_resource = self.before
            self.sums["crowd_moving"] += float(((world.pos != pos).any(axis=1) & was_crowd).sum())
            self.sums["cache_join"] += float((could_join_cache & cache_queued).sum())
            self.sums["resource_join"] += float((could_join_resource & (world.queue_of >= 4)).sum())
            for key, mask in (("crowd", was_crowd), ("could_join_cache", could_join_cache),
                              ("could_join_resource", could_join_resource)):
                self.denominators[key] += int(mask.sum())
        self.sums["crowd"] += float(crowd.sum())
        self.sums["in_cache_queues"] += float(cache_queued.sum())
        self.sums["docks_held"] += float(len(held))
        self.steps += 1
        can_join = world.last_result.action_mask[:, 4] & ~world.queued  # the mask the step just computed
        self.before = (crowd, world.pos.copy(), can_join & world.carrying, can_join & ~world.carrying)

    def table(self) -> dict[str, float]:
        out = {key: self.sums[key] / max(self.steps, 1) for key in MEASURES if key not in SHARES}
        out |= {key: self.sums[key] / max(self.denominators[of], 1) for key, of in SHARES.items()}
        return out


@click.command()
@probe_options(policies="formic,csaf11", teams="64,128")
@click.option("--steps", default=1024, show_default=True)
@click.option("--radius", default=8, show_default=True, help="Cells from the nest centre that count as its crowd.")
@click.option("--out", type=click.Path(dir_okay=False), help="Also write the table here as JSON.")
def main(policies, model, scenario_dir, size, teams, count, channel_empty, steps, radius, out) -> None:
    """Mean per step: carrying agents crowding the nest, agents queued at it, docks held."""
    configure_threads()
    results = []
    for row in probe_rows(stored_teams(scenario_dir, size, teams, count), policies, model, steps,
                          lambda: CrowdCounter(radius), channel_empty):
        results.append(row)
        click.echo(f"{row['policy']:8s} {row['agents']:4d} agents  food {row['food']:6.1f}  crowd {row['crowd']:5.1f}  "
                   f"in cache queues {row['in_cache_queues']:4.1f}  docks held {row['docks_held']:.2f}  "
                   f"crowd moving {row['crowd_moving']:.0%}  joins when it may: loaded {row['cache_join']:.0%}, "
                   f"empty {row['resource_join']:.0%}")
    if out:
        Path(out).write_text(json.dumps({"radius": radius, "steps": steps, "model": model, "results": results},
                                        indent=1))


if __name__ == "__main__":
    main()
