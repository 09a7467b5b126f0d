"""The evaluation matrix: settings (world size, team, obstacles, environment, length), the
stored scenarios of each, and the episodes (algorithm x scenario) to run.

Every algorithm runs on the very same scenario files. Layout seeds depend on ``--seed`` and
the world's layout parameters (size, obstacle density, capacity) but not on the team size or
the wipeouts: a setting's 50 layouts are the same for 16 and 128 agents and for the infinite
and wipeout environments, so the curves over team size and the wipeout lines are paired
comparisons on identical worlds.
"""

from __future__ import annotations

import hashlib
from collections.abc import Iterable
from dataclasses import dataclass
from pathlib import Path

from formic_world import Scenario, WorldConfig
from formic_world.scenario_sets import generate_set, load_set

# environment name -> (capacity, wipeouts); see wipeout_length for how long each lasts
ENVIRONMENTS: dict[str, tuple[str, int]] = {
    "infinite": ("infinite", 0),
    "finite": ("finite", 0),
    "wipeout": ("infinite", 3),
}
ENV_ORDER = ("infinite", "wipeout", "finite")
WIPEOUT_STEPS = 100


def wipeout_length(steps: int) -> int:
    """The paper's 100 steps; episodes shorter than 400 steps (quick tests) get steps // 4."""
    return max(1, min(WIPEOUT_STEPS, steps // 4))


def env_of(config: WorldConfig) -> str:
    """The environment name of a stored scenario's configuration."""
    names = {kind: name for name, kind in ENVIRONMENTS.items()}
    return names.get((config.capacity, config.wipeouts), f"{config.capacity}-w{config.wipeouts}")


def env_rank(env: str) -> int:
    """Where an environment comes in tables and sorted settings (unknown ones last)."""
    return ENV_ORDER.index(env) if env in ENV_ORDER else len(ENV_ORDER)


@dataclass(frozen=True)
class Setting:
    """One cell of the matrix, shared by all algorithms."""

    size: int
    agents: int
    obstacles: float
    env: str
    steps: int

    def world_config(self) -> WorldConfig:
        capacity, wipeouts = ENVIRONMENTS[self.env]
        return WorldConfig(
            height=self.size, width=self.size, n_agents=self.agents, obstacle_density=self.obstacles,
            capacity=capacity, wipeouts=wipeouts, wipeout_steps=wipeout_length(self.steps),
            episode_steps=self.steps,
        )

    def sort_key(self) -> tuple:
        return (self.size, self.steps, self.obstacles, env_rank(self.env), self.env, self.agents)


@dataclass(frozen=True)
class StoredScenario:
    """A scenario file of the set: what a worker loads, and what identifies its episodes."""

    path: Path
    setting: Setting
    seed: int
    digest: str  # hash of the canonical JSON: a changed file never reuses old results


@dataclass(frozen=True)
class PolicyOptions:
    """How the algorithms run: the learned policy's options (the baselines ignore them), and
    the pheromone variant of every world (the paper's out-of-distribution trail tests)."""

    model: str | None = None
    model_digest: str = ""
    greedy: bool = False
    no_pheromones: bool = False
    pheromone_variant: str = "standard"

    def variant(self, algorithm: str) -> str:
        """How this algorithm's runs differ from its plain form ("" for plain runs), e.g.
        ``greedy+no-pheromones`` or ``trails-flat``."""
        learned = algorithm == "formic"
        tags = (("greedy", learned and self.greedy), ("no-pheromones", learned and self.no_pheromones),
                (f"trails-{self.pheromone_variant}", self.pheromone_variant != "standard"))
        return "+".join(tag for tag, on in tags if on)


@dataclass(frozen=True)
class Task:
    """One episode: an algorithm on a stored scenario."""

    algorithm: str
    variant: str
    model: str | None
    model_digest: str
    greedy: bool
    no_pheromones: bool
    scenario: StoredScenario
    pheromone_variant: str = "standard"

    @property
    def key(self) -> str:
        s = self.scenario
        return "|".join((self.algorithm, self.variant, self.model_digest, s.path.name, s.digest, str(s.setting.steps)))


def layout_seed(seed: int, size: int, obstacles: float, capacity: str) -> int:
    """First scenario seed of a setting: a stable hash of --seed and the layout parameters."""
    text = f"{seed}|{size}|{obstacles:g}|{capacity}"
    return int.from_bytes(hashlib.sha256(text.encode()).digest()[:4], "big") % 2**30


def scenario_digest(scenario: Scenario) -> str:
    return hashlib.sha256(scenario.to_json().encode()).hexdigest()[:16]


def file_digest(path: str | Path) -> str:
    return hashlib.sha256(Path(path).read_bytes()).hexdigest()[:16]


def settings_grid(
    sizes: Iterable[int], teams: Iterable[int], obstacles: Iterable[float], envs: Iterable[str], steps: int
) -> list[Setting]:
    grid = {Setting(s, n, float(o), e, steps) for s in sizes for n in teams for o in obstacles for e in envs}
    return sorted(grid, key=Setting.sort_key)


def generate_matrix(
    settings: list[Setting], count: int, seed: int, directory: Path
) -> dict[Setting, list[StoredScenario]]:
    """Write (or keep, when identical) ``count`` scenarios per setting under ``directory``."""
    matrix = {}
    for setting in settings:
        config = setting.world_config()
        base = layout_seed(seed, setting.size, setting.obstacles, config.capacity)
        paths = generate_set(config, base, count, directory)
        matrix[setting] = [
            StoredScenario(path, setting, base + k, scenario_digest(Scenario.load(path)))
            for k, path in enumerate(paths)
        ]
    return matrix


def load_matrix(
    directory: Path,
    sizes: Iterable[int] | None = None,
    teams: Iterable[int] | None = None,
    obstacles: Iterable[float] | None = None,
    envs: Iterable[str] | None = None,
    steps: int | None = None,
) -> dict[Setting, list[StoredScenario]]:
    """Group the scenario files of ``directory`` by setting, keeping those the filters allow.

    Raises :class:`formic_world.ScenarioError` (naming the file) for a file that does not load.
    ``steps`` shortens the episodes; it may not exceed a file's episode length.
    """
    matrix: dict[Setting, list[StoredScenario]] = {}
    for path, scenario in load_set(Path(directory)):
        cfg = scenario.config
        horizon = cfg.episode_steps if steps is None else steps
        if horizon > cfg.episode_steps:
            raise ValueError(f"{path}: --steps {steps} exceeds the scenario's {cfg.episode_steps} steps")
        setting = Setting(cfg.height, cfg.n_agents, float(cfg.obstacle_density), env_of(cfg), horizon)
        if not _allowed(setting, sizes, teams, obstacles, envs):
            continue
        matrix.setdefault(setting, []).append(StoredScenario(path, setting, scenario.seed, scenario_digest(scenario)))
    return {k: matrix[k] for k in sorted(matrix, key=Setting.sort_key)}


def _allowed(setting: Setting, sizes, teams, obstacles, envs) -> bool:
    return (
        (sizes is None or setting.size in sizes)
        and (teams is None or setting.agents in teams)
        and (obstacles is None or any(abs(setting.obstacles - o) < 1e-9 for o in obstacles))
        and (envs is None or setting.env in envs)
    )


def plan_tasks(
    matrix: dict[Setting, list[StoredScenario]], algorithms: list[str], options: PolicyOptions
) -> list[Task]:
    """Every (algorithm, scenario) episode, scenario-major so a partial run covers all algorithms."""
    return [
        Task(name, options.variant(name), options.model if name == "formic" else None,
             options.model_digest if name == "formic" else "", options.greedy and name == "formic",
             options.no_pheromones and name == "formic", scenario, options.pheromone_variant)
        for scenarios in matrix.values()
        for scenario in scenarios
        for name in algorithms
    ]
