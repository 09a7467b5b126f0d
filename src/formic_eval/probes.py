"""Episodes for the measuring scripts (``scripts/nest_crowding.py``, ``trail_following.py``,
``homing.py``): a stored scenario played by one policy with a counter called after every step,
optionally with the pheromone channel empty as ``formic eval --no-pheromones`` tests it."""

from __future__ import annotations

import dataclasses
from collections.abc import Callable, Iterable, Iterator

import numpy as np

from formic_runtime.episode import EpisodeStats, run_episode
from formic_world import Scenario, World


def with_channel_empty(scenario: Scenario) -> Scenario:
    """The same scenario, its agents reading an empty pheromone channel (the world still lays it)."""
    return dataclasses.replace(scenario, config=scenario.config.replace(pheromones_visible=False))


def play(scenario: Scenario, policy: str, model: str | None, steps: int | None,
         on_step: Callable[[World], None], channel_empty: bool = False) -> EpisodeStats:
    """One episode of ``scenario`` (``steps``: its own when None), ``on_step`` after every step."""
    if channel_empty:
        scenario = with_channel_empty(scenario)
    return run_episode(scenario, policy, model=model, steps=steps, on_step=on_step)


def mean_over_scenarios(scenarios: Iterable[Scenario], policy: str, model: str | None, steps: int | None,
                        make_counter: Callable[[], Callable[[World], None]],
                        channel_empty: bool = False) -> dict[str, float]:
    """The food and a fresh counter's ``table()`` per scenario, each averaged over the scenarios
    (a measure a scenario could not define, NaN there, is averaged over the others)."""
    rows = []
    for scenario in scenarios:
        counter = make_counter()
        episode = play(scenario, policy, model, steps, counter, channel_empty)
        rows.append({"food": episode.food, **counter.table()})
    return {key: defined_mean([row[key] for row in rows]) for key in rows[0]}


def defined_mean(values: list[float]) -> float:
    """The mean of the values that are not NaN; NaN, without numpy's warning, when none is."""
    defined = [v for v in values if not np.isnan(v)]
    return float(np.mean(defined)) if defined else float("nan")


def probe_rows(teams: Iterable[tuple[int, list[Scenario]]], policies: str, model: str | None, steps: int | None,
               make_counter: Callable[[], Callable[[World], None]],
               channel_empty: bool = False) -> Iterator[dict]:
    """Per team size (with its stored scenarios) and policy (comma-separated), one row of a
    measuring script's table: policy, agents, scenarios and ``mean_over_scenarios``."""
    for team, scenarios in teams:
        for policy in policies.split(","):
            yield {"policy": policy, "agents": team, "scenarios": len(scenarios),
                   **mean_over_scenarios(scenarios, policy, model, steps, make_counter, channel_empty)}
