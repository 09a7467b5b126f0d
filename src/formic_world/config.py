"""Every parameter of the world in one typed object (SPEC §1-4 defaults).

Nothing about the world's rules is a constant buried in code: generation, queues, loads,
pheromones, observation and rewards all read their numbers from :class:`WorldConfig`.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import math
from dataclasses import dataclass, field
from fractions import Fraction
from functools import cached_property
from typing import Any

from .limits import MAX_AGENTS, MAX_EPISODE_STEPS, MAX_QUEUE_LEN, MAX_SIDE, MAX_VIEW_SIZE, check_at_most

PHEROMONE_VARIANTS = ("standard", "flat", "noisy", "random")
CAPACITY_MODES = ("infinite", "finite")
TIMINGS = ("reference", "nominal")
AGENT_ORDERS = ("random", "id")
TRAINING_FILTERS = ("paper", "reference")
MIN_SIDE = 15  # cells, a world's height and width: no smaller one lays out (the upper limit: limits.MAX_SIDE)
TEST_EPISODE_STEPS = 1024  # the paper's test episodes (SPEC §1); WorldConfig's default, 512, is training's


@dataclass(frozen=True)
class RewardConfig:
    """Per-step rewards (paper Table "reward structure"; SPEC §4)."""

    move: float = -0.05  # every step spent moving or trying to move
    queue_wait: float = -0.05  # every step waiting or being served in a queue
    collect: float = 10.0  # leaving a resource full
    deposit: float = 10.0  # leaving a cache empty
    join_right: float = 0.0  # entering the right queue
    join_wrong: float = -1.0  # trying to enter the wrong type of queue
    join_nothing: float = -0.05  # JOIN with no queue in reach: a wasted step, like a failed move
    blocked: float = -0.05  # a move that fails (wall, obstacle, agent): the paper charges it as a move
    # Collection pays collect * exp(-collect_distance_decay * d), d the resource cell's Euclidean
    # distance to the nest centre (0: flat, the paper; the reference code used 0.0115).
    collect_distance_decay: float = 0.0


# Named reward sets (SPEC §4): the paper's table, and what the authors' code trained with.
REWARD_PRESETS: dict[str, RewardConfig] = {
    "paper": RewardConfig(),
    "reference": RewardConfig(deposit=5.0, collect_distance_decay=0.0115, blocked=-0.5, join_nothing=-0.5),
}


@dataclass(frozen=True)
class WorldConfig:
    """World parameters. ``height``/``width`` may differ; every experiment uses squares."""

    height: int = 128
    width: int = 128
    n_agents: int = 32
    queue_len: int = 5
    obstacle_density: float = 0.0
    capacity: str = "infinite"  # "infinite" | "finite"
    capacity_min: int = 4  # finite resources hold a uniform integer in [min, max] units
    capacity_max: int = 8
    gather_rate: float = 0.1
    dropoff_rate: float = 0.5
    episode_steps: int = 512
    # Service timing (SPEC §1 "Timing"): "reference" reproduces the authors' code (a load takes
    # 11 steps, a queue that moved up serves nobody that step); "nominal" is exactly 1/rate.
    timing: str = "reference"
    # Who acts first each step: a fresh seeded permutation (SPEC §1), or agent id order (the
    # reference code's loop, used only by the reference baseline variants).
    agent_order: str = "random"
    # Pheromones (SPEC §2)
    alpha: float = 0.97  # per-deposit decay of an agent's intensity
    beta: float = 0.99  # per-step evaporation of the map
    pheromone_variant: str = "standard"
    deposit_strength: float = 1.0  # I_c of the curriculum
    highway_intensity: float = 0.0  # I_h of the curriculum (training only)
    wipeouts: int = 0
    wipeout_steps: int = 100
    # Observation (SPEC §3)
    view_size: int = 11
    pheromones_visible: bool = True  # False: channel 7 reads 0 (the paper's ablation)
    # Training-only start: a random number in [0, min(this, N)] agents begin in cache queues loaded
    training_start: bool = False
    training_start_max_queued: int = 20
    # Training filter for carrying agents (SPEC §4): "paper" forbids moves away from the nest;
    # "reference" allows only the (at most two) moves best aligned with the nest direction.
    training_filter: str = "paper"
    rewards: RewardConfig = field(default_factory=RewardConfig)

    def __post_init__(self) -> None:
        for name, limit in (("height", MAX_SIDE), ("width", MAX_SIDE), ("n_agents", MAX_AGENTS),
                            ("view_size", MAX_VIEW_SIZE), ("episode_steps", MAX_EPISODE_STEPS),
                            ("queue_len", MAX_QUEUE_LEN)):
            check_at_most(name, getattr(self, name), limit)
        if self.height < MIN_SIDE or self.width < MIN_SIDE:
            raise ValueError(f"world must be at least {MIN_SIDE}x{MIN_SIDE}, got {self.height}x{self.width}")
        if self.n_agents < 1:
            raise ValueError("n_agents must be >= 1")
        if self.queue_len < 1:
            raise ValueError(f"queue_len must be >= 1, got {self.queue_len}")
        for name, allowed in (
            ("capacity", CAPACITY_MODES), ("timing", TIMINGS), ("agent_order", AGENT_ORDERS),
            ("training_filter", TRAINING_FILTERS), ("pheromone_variant", PHEROMONE_VARIANTS),
        ):
            value = getattr(self, name)
            if value not in allowed:
                raise ValueError(f"{name} must be one of {allowed}, got {value!r}")
        if self.view_size % 2 != 1 or self.view_size < 3:
            raise ValueError(f"view_size must be odd and >= 3, got {self.view_size}")
        if not 0.0 <= self.obstacle_density < 0.5:
            raise ValueError(f"obstacle_density must be in [0, 0.5), got {self.obstacle_density}")
        if not 0.0 <= self.highway_intensity <= 1.0 or not 0.0 <= self.deposit_strength <= 1.0:
            raise ValueError("highway_intensity and deposit_strength must be in [0, 1]")
        if self.episode_steps < 1:
            raise ValueError(f"episode_steps must be >= 1, got {self.episode_steps}")
        if self.wipeouts < 0:
            raise ValueError(f"wipeouts must be >= 0, got {self.wipeouts}")
        if self.wipeouts * self.wipeout_steps > self.episode_steps:
            raise ValueError("wipeouts do not fit in the episode")
        if not 1 <= self.capacity_min <= self.capacity_max:
            raise ValueError("need 1 <= capacity_min <= capacity_max")
        for name in ("gather_rate", "dropoff_rate"):
            rate = getattr(self, name)
            if not 0 < rate <= 1:
                raise ValueError(f"{name} must be in (0, 1], got {rate}")
        self.load_denominator  # validates that rates are exact fractions

    @cached_property  # the world steps read it: Fractions cost 30% of a 16-agent step
    def load_denominator(self) -> int:
        """Loads are integers in units of 1/D so a load takes exactly 1/rate steps."""
        return math.lcm(_fraction(self.gather_rate).denominator, _fraction(self.dropoff_rate).denominator)

    @cached_property
    def gather_ticks(self) -> int:
        return int(_fraction(self.gather_rate) * self.load_denominator)

    @cached_property
    def dropoff_ticks(self) -> int:
        return int(_fraction(self.dropoff_rate) * self.load_denominator)

    @cached_property
    def gather_holds(self) -> bool:
        """Reference timing: a full load is released one service step late when the
        reference's floating-point accumulation of ``gather_rate`` falls short of 1."""
        return self._holds(self.gather_rate, self.gather_ticks)

    @cached_property
    def dropoff_holds(self) -> bool:
        """As :attr:`gather_holds`, for emptying at a cache (0.5 adds up exactly: no hold)."""
        return self._holds(self.dropoff_rate, self.dropoff_ticks)

    @cached_property
    def gather_steps(self) -> int:
        """Service steps to fill a unit load at a resource (10 nominal, 11 reference)."""
        return -(-self.load_denominator // self.gather_ticks) + int(self.gather_holds)

    @cached_property
    def dropoff_steps(self) -> int:
        """Service steps to empty a unit load at a cache (2 under both timings)."""
        return -(-self.load_denominator // self.dropoff_ticks) + int(self.dropoff_holds)

    def _holds(self, rate: float, ticks: int) -> bool:
        return self.timing == "reference" and _float_steps(rate) > -(-self.load_denominator // ticks)

    @property
    def serve_after_move_up(self) -> bool:
        """Nominal timing serves spot 0 in the step its queue moved up; the reference does not."""
        return self.timing == "nominal"

    @property
    def effective_alpha(self) -> float:
        """The ``flat`` variant sets alpha = beta so a trail carries no gradient."""
        return self.beta if self.pheromone_variant == "flat" else self.alpha

    def replace(self, **changes: Any) -> "WorldConfig":
        if "rewards" in changes and isinstance(changes["rewards"], dict):
            changes["rewards"] = RewardConfig(**changes["rewards"])
        return dataclasses.replace(self, **changes)

    def to_dict(self) -> dict[str, Any]:
        return dataclasses.asdict(self)

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> "WorldConfig":
        unknown = set(data) - {f.name for f in dataclasses.fields(cls)}
        if unknown:
            raise ValueError(f"unknown world configuration keys: {sorted(unknown)}")
        data = dict(data)
        if "rewards" in data:
            bad = set(data["rewards"]) - {f.name for f in dataclasses.fields(RewardConfig)}
            if bad:
                raise ValueError(f"unknown reward keys: {sorted(bad)}")
            data["rewards"] = RewardConfig(**data["rewards"])
        return cls(**data)

    def digest(self) -> str:
        """Short stable hash of the configuration, recorded with runs."""
        text = json.dumps(self.to_dict(), sort_keys=True)
        return hashlib.sha256(text.encode()).hexdigest()[:16]


def _float_steps(rate: float) -> int:
    """Steps the reference code needs to fill (or empty) a unit load by adding ``rate`` in
    floating point until the sum reaches 1: 11 for 0.1 (ten additions give 0.9999999999999999)."""
    total, steps = 0.0, 0
    while total < 1.0:
        total += rate
        steps += 1
    return steps


def _fraction(rate: float) -> Fraction:
    """``rate`` as an exact fraction with a denominator of at most 10 000."""
    frac = Fraction(rate).limit_denominator(10_000)
    if abs(float(frac) - rate) > 1e-12:
        raise ValueError(f"rate {rate} is not a simple fraction")
    return frac


def resource_count_range(height: int, width: int) -> tuple[int, int]:
    """Inclusive range of the resource count (SPEC §1): m = H*W*10/2304."""
    m = height * width * 10 / 2304
    return max(10, int(m // 2)), max(10, int(3 * m // 2))
