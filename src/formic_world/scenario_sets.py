"""Stored scenario sets: one JSON file per scenario, named by setting and seed."""

from __future__ import annotations

from pathlib import Path

from .config import WorldConfig
from .scenario import Scenario, ScenarioError, generate_scenario


def generate_set(config: WorldConfig, seed: int, count: int, directory: Path) -> list[Path]:
    """Scenarios with seeds seed..seed+count-1; existing identical files are kept."""
    name = (
        f"s{config.height}_n{config.n_agents}_o{config.obstacle_density:g}_{config.capacity}"
        f"_w{config.wipeouts}_t{config.episode_steps}"
    )
    paths = []
    for k in range(count):
        scenario = generate_scenario(config, seed + k)
        path = Path(directory) / f"{name}_seed{seed + k}.json"
        if not path.exists() or path.read_text() != scenario.to_json():
            scenario.save(path)
        paths.append(path)
    return paths


def load_set(path: Path) -> list[tuple[Path, Scenario]]:
    """A scenario file, or every ``*.json`` scenario in a directory (sorted by name)."""
    files = sorted(Path(path).glob("*.json")) if Path(path).is_dir() else [Path(path)]
    if not files:
        raise ScenarioError(f"{path}: no scenario files (*.json)")
    return [(f, Scenario.load(f)) for f in files]


def first_stored(directory: Path, size: int, agents: int, count: int) -> list[Scenario]:
    """The first ``count`` stored scenarios (by name) of one 1024-step-protocol setting: a
    ``size``-sided world, ``agents`` agents, infinite resources, no obstacles, no wipeouts."""
    prefix = f"s{size}_n{agents}_o0_infinite_w0_"
    files = sorted(Path(directory).glob(f"{prefix}*.json"))[:count]
    if not files:
        raise ScenarioError(f"no stored scenarios {prefix}* in {directory}")
    return [Scenario.load(f) for f in files]


def describe(scenario: Scenario) -> dict:
    cfg = scenario.config
    return {
        "seed": scenario.seed,
        "height": cfg.height,
        "width": cfg.width,
        "agents": cfg.n_agents,
        "resources": len(scenario.resources),
        "capacity": cfg.capacity,
        "obstacles": len(scenario.obstacles),
        "wipeout_starts": list(scenario.wipeout_starts),
    }
