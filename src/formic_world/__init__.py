"""ForMIC world: the simulation core (no ROS), scenarios, rendering and a PettingZoo wrapper.

The names below load on first use (PEP 562), so a process that needs only a leaf module (an
agent host reading ``formic_world.geometry``) does not pay for numba and scipy at start-up."""

from __future__ import annotations

import importlib

_HOMES = {
    "REWARD_PRESETS": "config", "RewardConfig": "config", "WorldConfig": "config",
    "Scenario": "scenario", "ScenarioError": "scenario", "generate_scenario": "scenario",
    "NO_ACTION": "world", "StepResult": "world", "World": "world", "make_world": "world",
}

__all__ = [*_HOMES, "parallel_env"]


def __getattr__(name: str):
    if name in _HOMES:
        return getattr(importlib.import_module(f".{_HOMES[name]}", __name__), name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


def parallel_env(**kwargs):
    """PettingZoo ParallelEnv over the core; keyword arguments are WorldConfig fields."""
    from .pettingzoo_env import parallel_env as _parallel_env

    return _parallel_env(**kwargs)
