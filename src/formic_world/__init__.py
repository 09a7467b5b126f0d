"""ForMIC world: the simulation core (no ROS), scenarios, rendering and a PettingZoo wrapper."""

from .config import REWARD_PRESETS, RewardConfig, WorldConfig
from .scenario import Scenario, ScenarioError, generate_scenario
from .world import NO_ACTION, StepResult, World, make_world

__all__ = [
    "NO_ACTION",
    "REWARD_PRESETS",
    "RewardConfig",
    "Scenario",
    "ScenarioError",
    "StepResult",
    "World",
    "WorldConfig",
    "generate_scenario",
    "make_world",
    "parallel_env",
]


def parallel_env(**kwargs):
    """PettingZoo ParallelEnv over the core; keyword arguments are WorldConfig fields."""
    from .pettingzoo_env import parallel_env as _parallel_env

    return _parallel_env(**kwargs)
