"""The world as a PettingZoo ``ParallelEnv`` ("formic_v0"), for users of standard MARL tools.

Agents are "agent_0" .. "agent_{N-1}"; each observes the SPEC §3 window (8×V×V float32 in
[0, 1]) and picks one of 5 actions (0 north, 1 east, 2 south, 3 west, 4 JOIN). Infos carry
the environment's action mask (int8), the agent's load, whether it is queued (its action is
then ignored) and its position (odometry, as the project's policies receive it).

Seeding: ``reset(seed=s)`` plays ``generate_scenario(config, s)``, so an episode here is the
same world as ``World(generate_scenario(config, s))``; each later ``reset()`` without a seed
plays seed s+1, s+2, ... (a random first seed if none was ever given).
``reset(options={"scenario": scenario})`` plays a stored scenario, whose own configuration
governs the dynamics (it must match this env's grid size, team size and view size).

Episodes never terminate; every agent is truncated at ``max_cycles`` steps (default the
configuration's ``episode_steps``) and the agent list then empties.

Agents missing from the actions dict do nothing that step (the core's ``NO_ACTION``: no move,
no deposit, reward 0), exactly like a late agent node in the ROS system.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from gymnasium import spaces
from pettingzoo import ParallelEnv

from .config import WorldConfig
from .geometry import N_ACTIONS
from .observation import N_CHANNELS
from .render import render_frame
from .scenario import generate_scenario
from .world import NO_ACTION, StepResult, World

_SHAPE_FIELDS = ("height", "width", "n_agents", "view_size")


def parallel_env(
    config: WorldConfig | None = None,
    render_mode: str | None = None,
    max_cycles: int | None = None,
    **config_fields: Any,
) -> "FormicParallelEnv":
    """A ForMIC ParallelEnv; keyword arguments are ``WorldConfig`` fields (e.g. height=24)."""
    config = (config or WorldConfig()).replace(**config_fields)
    return FormicParallelEnv(config, render_mode=render_mode, max_cycles=max_cycles)


class FormicParallelEnv(ParallelEnv):
    metadata = {
        "name": "formic_v0", "render_modes": ["rgb_array"], "render_fps": 20, "is_parallelizable": True,
    }

    def __init__(self, config: WorldConfig, render_mode: str | None = None, max_cycles: int | None = None):
        if render_mode not in (None, "rgb_array"):
            raise ValueError(f"render_mode must be None or 'rgb_array', got {render_mode!r}")
        if config.highway_intensity > 1:
            # the pheromone channel reads max(P, I_h * highways); above 1 it leaves the Box
            raise ValueError("highway_intensity must be <= 1 for observations in [0, 1]")
        self.config = config
        self.render_mode = render_mode
        self.max_cycles = config.episode_steps if max_cycles is None else max_cycles
        self.possible_agents = [f"agent_{i}" for i in range(config.n_agents)]
        self.agents: list[str] = []
        self.world: World | None = None
        self.scenario_seed: int | None = None  # seed of the scenario being played
        v = config.view_size
        self._observation_space = spaces.Box(0.0, 1.0, (N_CHANNELS, v, v), np.float32)
        self._action_space = spaces.Discrete(N_ACTIONS)
        self.state_space = spaces.Box(0.0, 1.0, (N_CHANNELS, config.height, config.width), np.float32)

    def observation_space(self, agent: str) -> spaces.Box:
        return self._observation_space  # one shared object, as the API test requires

    def action_space(self, agent: str) -> spaces.Discrete:
        return self._action_space

    # ------------------------------------------------------------------ reset
    def reset(self, seed: int | None = None, options: dict | None = None):
        scenario = (options or {}).get("scenario")
        if scenario is not None:
            for name in _SHAPE_FIELDS:
                ours, theirs = getattr(self.config, name), getattr(scenario.config, name)
                if ours != theirs:
                    raise ValueError(f"scenario has {name}={theirs}, this env was built for {name}={ours}")
            self.scenario_seed = scenario.seed
        else:
            if seed is not None:
                self.scenario_seed = int(seed)
            elif self.scenario_seed is None:
                self.scenario_seed = int(np.random.SeedSequence().generate_state(1)[0])
            else:
                self.scenario_seed += 1
            scenario = generate_scenario(self.config, self.scenario_seed)
        if self.world is None:
            self.world = World(scenario)  # reset by its constructor
            result = self.world.last_result
        else:
            result = self.world.reset(scenario)
        self.agents = self.possible_agents[:]
        return self._observations(result), self._infos(result)

    # ------------------------------------------------------------------- step
    def step(self, actions: dict[str, int]):
        if not self.agents:
            return {}, {}, {}, {}, {}
        unknown = set(actions) - set(self.agents)
        if unknown:
            raise ValueError(f"actions for agents that are not live: {sorted(unknown)}")
        world = self.world
        ids = np.array([int(name.rsplit("_", 1)[1]) for name in actions], dtype=np.int64)
        chosen = np.full(world.config.n_agents, NO_ACTION, dtype=np.int64)
        chosen[ids] = [int(a) for a in actions.values()]
        result = world.step(chosen)
        truncated = world.done or world.t >= self.max_cycles
        agents = self.agents
        observations = self._observations(result)
        rewards = {name: float(result.rewards[i]) for i, name in enumerate(agents)}
        terminations = dict.fromkeys(agents, False)
        truncations = dict.fromkeys(agents, truncated)
        infos = self._infos(result)
        if truncated:
            self.agents = []
        return observations, rewards, terminations, truncations, infos

    def _observations(self, result: StepResult) -> dict[str, np.ndarray]:
        return {name: result.observations[i] for i, name in enumerate(self.agents)}

    def _infos(self, result: StepResult) -> dict[str, dict[str, Any]]:
        world = self.world
        mask = result.action_mask.astype(np.int8)
        loads, queued, pos = world.loads, world.queued, world.pos
        return {
            name: {
                "action_mask": mask[i], "load": float(loads[i]), "queued": bool(queued[i]),
                "position": pos[i].copy(),
            }
            for i, name in enumerate(self.agents)
        }

    # ------------------------------------------------------------ the rest
    def render(self) -> np.ndarray | None:
        if self.render_mode is None or self.world is None:
            return None
        return render_frame(self.world)

    def state(self) -> np.ndarray:
        """The observation channels over the whole world, (8, H, W) float32."""
        observer = self.world.observer
        return observer.maps[(slice(None),) + observer.interior].copy()

    def close(self) -> None:
        self.world = None

