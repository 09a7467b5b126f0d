"""Training settings: :class:`TrainConfig`, its presets and its command-line and JSON forms.

Every mode is a ``Literal`` type, checked when a config is made (``--set action_filter=mask2``
is an error naming the allowed values, not a silent fall-through to a default branch).
"""

from __future__ import annotations

import dataclasses
import functools
import json
import math
import typing
from dataclasses import dataclass
from pathlib import Path
from typing import Literal

from formic_agent.inputs import NETWORK_PRESETS
from formic_runtime.registry import POLICY_NAMES
from formic_world import REWARD_PRESETS, RewardConfig
from formic_world.limits import MAX_AGENTS, MAX_EPISODE_STEPS, MAX_SIDE, MAX_VIEW_SIZE, check_at_most

# A training world's side is drawn even within its range (worlds.sample_scenarios, rounding down), and
# no side below formic_world's MIN_SIDE (15) lays out: a range starts at 16.
MIN_TRAINING_SIDE = 16
MAX_SEED = 2**63 - 1  # a signed 64-bit integer (torch.manual_seed overflowed past 2**64 - 1: a traceback)
MAX_THREADS = 1024  # far above any machine's cores; torch crashes (SIGSEGV) asked for 100,000


@dataclass
class TrainConfig:
    """Every training setting, one line of help each; why the non-paper ones exist and what
    they measured: docs/training.md, "The settings". A setting that can be off is None when off;
    its :data:`OFF_SPELLINGS` value (what ``--set``, a recipe and older ``config.json`` files say)
    is read as None."""

    # the preset these defaults are (PRESETS["paper"] is TrainConfig()); the commands' --preset defaults
    # to "cpu", the one that trains on a CPU. Every saved config.json names its preset.
    preset: Literal["paper", "cpu"] = "paper"
    network: str = "paper"  # a NETWORK_PRESETS name
    seed: int = 0
    # Meta-agent environments
    teams: tuple[int, ...] = (16, 24, 32, 48)  # agents in each world
    learning_agents: int | None = 8  # the first N agents of each world learn, the rest act with the policy (None: all)
    world_sizes: tuple[tuple[int, int], ...] = ((20, 96), (20, 96), (40, 96), (64, 128))  # side range per world
    obstacle_range: tuple[float, float] = (0.0, 0.05)
    episode_steps: int = 512
    view_size: int = 11
    # Algorithm
    rollout_steps: int = 512  # steps per update (512 = whole episodes, as the paper)
    epochs: int = 1
    minibatches: int = 1
    clip: float | None = None  # PPO ratio clip; None = plain actor-critic (the paper)
    target_kl: float | None = None  # stop an update's minibatches once approx_kl > 1.5 x this (None: off)
    gamma: float = 0.95
    gae_lambda: float = 1.0  # 1.0 = n-step bootstrapped returns (the paper)
    value_coef: float = 0.5
    queued_value_loss: bool = False  # train the critic on queued steps too (beyond the paper)
    entropy_coef: float = 0.01
    valid_coef: float = 0.5
    valid_actions: Literal["all", "moves"] = "all"  # the valid-action loss on every logit (paper) or the moves only
    valid_loss: Literal["bce", "mass"] = "bce"  # the paper's sigmoid predictor, or -log P(valid move)
    valid_join_coef: float = 0.0  # the paper's BCE on the JOIN logit alone, beside valid_loss (0 = off)
    mask_join: bool = True  # with action_filter="mask": also mask an invalid JOIN
    filter_anneal_start: int = 0  # filter annealing (beyond the paper): P(filtered) falls linearly from ...
    filter_anneal_end: int = 0  # ... filter_initial at filter_anneal_start to filter_final at filter_anneal_end
    filter_initial: float = 1.0
    filter_final: float = 1.0
    # the schedule clock (formic_trainer.schedule): the filter's and highways' schedules pause over
    # episode sets whose rolling food < anneal_hold x its peak over the last anneal_memory sets (None: never)
    anneal_hold: float | None = None
    anneal_memory: int = 20
    schedule_end: int | None = None  # end the run once the schedule clock reaches this (total_episodes caps it; None: off)
    init_weights: str | None = None  # start the network from this checkpoint (warm start / fine-tune)
    weight_average: float | None = None  # decay of a moving average of the weights, as averaged.pt (None: off)
    optimizer: Literal["nadam", "adam"] = "nadam"
    lr: float = 5e-6
    lr_warmup: int = 0  # ramp the learning rate up over the first N updates of a run (0 = off)
    max_grad_norm: float = 10.0
    update_precision: Literal["fp32", "bf16"] = "fp32"  # bf16: the update's forward+backward under bf16 autocast
    loss_reduction: Literal["sum", "mean"] = "sum"  # "sum": gradients of all learning agents are summed (paper)
    normalize_advantages: bool = False
    reward_scale: float = 1.0
    team_reward: float = 0.0  # each reward becomes (1-f)*own + f*(its world's mean) (beyond the paper)
    imitate: str | None = None  # a baseline whose actions are imitation targets (DAgger style; None: off)
    imitation_coef: float = 0.0
    imitation_agents: Literal["loaded", "all"] = "loaded"  # whose actions are imitation targets
    imitation_radius: int | None = None  # ... within this many cells of the nest centre (None: anywhere)
    # Techniques (the paper's ablation switches)
    action_filter: Literal["replace", "mask", "none"] = "replace"  # replace (paper); mask: mask invalid logits
    training_filter: Literal["paper", "reference"] = "paper"  # carrying agents' filter (SPEC §4)
    rewards: Literal["paper", "reference"] = "paper"  # a formic_world.REWARD_PRESETS name (SPEC §4)
    reward_overrides: str = ""  # single rewards over the preset's, e.g. "deposit=10,blocked=-0.5"
    pheromones: bool = True  # False: train (and test) without pheromones
    curriculum: bool = True
    curriculum_start: int = 5000
    curriculum_end: int = 10000
    training_start: bool = True  # some agents start in cache queues loaded (reference behaviour)
    # Fall guard (formic_trainer.guard): keep best.pt, roll back to it when the rolling food falls
    guard_drop: float | None = None  # roll back when the rolling food < guard_drop x its best (None: no guard)
    guard_window: int = 5  # episode sets in the rolling food mean
    guard_after: int = 0  # watch the episode sets played from this episode on
    guard_restart: int | None = None  # from this episode on the guard's best starts again (None: never)
    guard_max: int = 3  # rollbacks at most; after them the guard only logs
    guard_lr_factor: float = 0.5  # each rollback multiplies the learning rate by this
    # Run
    total_episodes: int = 24000  # environment episodes (summed over meta-agents)
    checkpoint_every: int = 1  # episode sets (one episode in every meta-agent world)
    threads: int = 1

    def __post_init__(self) -> None:
        for name, value in off_as_none({name: getattr(self, name) for name in OFF_SPELLINGS}).items():
            setattr(self, name, value)
        for name, allowed in _choices().items():
            if getattr(self, name) not in allowed:
                raise ValueError(f"{name} must be one of {', '.join(map(repr, allowed))}, not {getattr(self, name)!r}")
        if self.network not in NETWORK_PRESETS:
            raise ValueError(f"network must be one of {', '.join(map(repr, NETWORK_PRESETS))}, not {self.network!r}")
        for name in ("weight_average", "guard_drop", "anneal_hold"):
            if getattr(self, name) is not None and not 0.0 < getattr(self, name) < 1.0:
                raise ValueError(f"{name} must be in (0, 1), or None or 0 for off, not {getattr(self, name)}")
        for name in ("clip", "target_kl", "imitation_radius", "guard_restart", "schedule_end"):
            if getattr(self, name) is not None and getattr(self, name) <= 0:
                raise ValueError(f"{name} must be > 0, or None or 0 for off, not {getattr(self, name)}")
        if self.learning_agents is not None and self.learning_agents < 1:  # 0 would train on no agent
            raise ValueError(f"learning_agents must be >= 1, or None or -1 for all, not {self.learning_agents}")
        if self.imitate is not None and self.imitate not in POLICY_NAMES:
            raise ValueError(f"imitate must be one of {', '.join(POLICY_NAMES)}, or none for off, not {self.imitate!r}")
        if not 0.0 <= self.filter_initial <= 1.0:
            raise ValueError(f"filter_initial is a probability in [0, 1], not {self.filter_initial}")
        if not 0.0 < self.guard_lr_factor <= 1.0 or self.anneal_memory < 1:
            raise ValueError(f"guard_lr_factor must be in (0, 1] and anneal_memory >= 1, not "
                             f"{self.guard_lr_factor} and {self.anneal_memory}")
        if self.guard_window < 1 or self.guard_max < 0 or self.guard_after < 0:
            raise ValueError("guard_max and guard_after must be >= 0 and guard_window >= 1")
        self._check_ranges()
        reward_config(self)  # a bad reward_overrides fails here, not at the first episode
        if len(self.world_sizes) < len(self.teams):
            raise ValueError(f"{len(self.teams)} teams but {len(self.world_sizes)} world_sizes: give one side "
                             "range per team (--set world_sizes=40-96,64-128)")

    def _check_ranges(self) -> None:
        """The numbers' ranges, so that a bad one fails here, naming its setting, and not deep in a
        world or as a nan loss many updates later."""
        for f in dataclasses.fields(self):
            value = getattr(self, f.name)
            if isinstance(value, float) and not math.isfinite(value):
                raise ValueError(f"{f.name} must be a finite number, not {value}")
        for name, low, high in (("seed", 0, None), ("episode_steps", 1, MAX_EPISODE_STEPS), ("rollout_steps", 1, None),
                                ("epochs", 1, None), ("minibatches", 1, None), ("threads", 1, None),
                                ("checkpoint_every", 1, None), ("total_episodes", 0, None), ("lr_warmup", 0, None),
                                ("curriculum_start", 0, None), ("curriculum_end", 0, None),
                                ("filter_anneal_start", 0, None), ("filter_anneal_end", 0, None)):
            value = getattr(self, name)
            if value < low or (high is not None and value > high):
                raise ValueError(f"{name} must be {f'in [{low}, {high}]' if high is not None else f'>= {low}'}, "
                                 f"not {value}")
        check_at_most("seed", self.seed, MAX_SEED)
        check_at_most("threads", self.threads, MAX_THREADS)
        if not self.teams or not all(1 <= n <= MAX_AGENTS for n in self.teams):
            raise ValueError(f"teams must be team sizes of 1 to {MAX_AGENTS}, not {','.join(map(str, self.teams))}")
        if not all(MIN_TRAINING_SIDE <= lo <= hi <= MAX_SIDE for lo, hi in self.world_sizes):
            raise ValueError(f"world_sizes must be MIN-MAX side ranges within {MIN_TRAINING_SIDE}-{MAX_SIDE}, not "
                             + ",".join(f"{lo}-{hi}" for lo, hi in self.world_sizes))
        low, high = self.obstacle_range
        if not 0.0 <= low <= high < 0.5:
            raise ValueError(f"obstacle_range must be densities 0 <= MIN <= MAX < 0.5, not {low}, {high}")
        if not 3 <= self.view_size <= MAX_VIEW_SIZE or self.view_size % 2 == 0:
            raise ValueError(f"view_size must be odd, 3 to {MAX_VIEW_SIZE}, not {self.view_size}")
        for name, low, high in (("gamma", 0.0, 1.0), ("gae_lambda", 0.0, 1.0), ("filter_final", 0.0, 1.0),
                                ("team_reward", 0.0, 1.0)):
            if not low <= getattr(self, name) <= high:
                raise ValueError(f"{name} must be in [{low:g}, {high:g}], not {getattr(self, name)}")
        for name in ("lr", "max_grad_norm", "reward_scale"):
            if not getattr(self, name) > 0:
                raise ValueError(f"{name} must be > 0, not {getattr(self, name)}")
        for name in ("value_coef", "entropy_coef", "valid_coef", "valid_join_coef", "imitation_coef"):
            if getattr(self, name) < 0:  # a loss weight: a negative one trains its loss the wrong way
                raise ValueError(f"{name} must be >= 0, not {getattr(self, name)}")

    def to_dict(self) -> dict:
        return dataclasses.asdict(self)


# the settings that are None when off (learning_agents: when every agent learns), each with the value
# that said so before: TOML has no None, so a recipe still writes it, and so may --set; config.json
# files and checkpoints written before hold it. A TrainConfig reads it as None.
OFF_SPELLINGS: dict[str, float | int | str] = {
    "learning_agents": -1, "clip": 0.0, "target_kl": 0.0, "anneal_hold": 0.0, "init_weights": "",
    "weight_average": 0.0, "imitate": "", "imitation_radius": 0, "guard_drop": 0.0, "guard_restart": 0,
    "schedule_end": 0,
}


def off_as_none(settings: dict) -> dict:
    """``settings`` (TrainConfig fields by name, e.g. a checkpoint's ``train_config``) with every
    :data:`OFF_SPELLINGS` value as None, as a TrainConfig holds it."""
    return {name: None if name in OFF_SPELLINGS and value == OFF_SPELLINGS[name] else value
            for name, value in settings.items()}


def typed_example(cfg: TrainConfig, name: str):
    """A value of the type setting ``name`` takes: ``cfg``'s, or its off spelling where that is None."""
    value = getattr(cfg, name)
    return OFF_SPELLINGS[name] if value is None else value


def require_distributable(cfg: TrainConfig) -> None:
    """Distributed training (``formic train-ros``, ``formic trainer``) runs the settings whose
    inputs its processes see; a ValueError names the one it cannot, and what to do instead."""
    if cfg.imitate is not None:
        raise ValueError("imitation runs its demonstrator beside the training worlds; train it in-process "
                         "(formic train)")
    if cfg.anneal_hold is not None:
        raise ValueError("anneal_hold moves the filter's and highways' schedules with the trainer's food record, "
                         "which the training worlds do not see; train it in-process (formic train) or set "
                         "anneal_hold=0")


def reward_config(cfg: TrainConfig) -> RewardConfig:
    """The training worlds' rewards: the ``rewards`` preset with ``reward_overrides`` applied."""
    fields = {f.name for f in dataclasses.fields(RewardConfig)}
    changes: dict[str, float] = {}
    for item in filter(None, (part.strip() for part in cfg.reward_overrides.split(","))):
        name, sep, text = item.partition("=")
        if not sep or name.strip() not in fields:
            raise ValueError(f"reward_overrides: {item!r} is not FIELD=NUMBER with a reward field "
                             f"({', '.join(sorted(fields))})")
        try:
            changes[name.strip()] = float(text)
        except ValueError:
            raise ValueError(f"reward_overrides: {name.strip()} needs a number, not {text!r}") from None
        if not math.isfinite(changes[name.strip()]):  # a nan or inf reward is a nan loss
            raise ValueError(f"reward_overrides: {name.strip()} needs a finite number, not {text!r}")
    return dataclasses.replace(REWARD_PRESETS[cfg.rewards], **changes)


@functools.cache
def _choices() -> dict[str, tuple[str, ...]]:
    """The allowed values of every Literal-typed field."""
    hints = typing.get_type_hints(TrainConfig, globalns=globals())
    return {name: typing.get_args(hint) for name, hint in hints.items() if typing.get_origin(hint) is Literal}


assert set(_choices()["rewards"]) == set(REWARD_PRESETS), "rewards must name formic_world.REWARD_PRESETS"


PRESETS = {
    "paper": TrainConfig(),
    # PPO with GAE on a small network, every agent learning, masked sampling with annealing
    "cpu": TrainConfig(
        preset="cpu", network="cpu", learning_agents=None,
        rollout_steps=128, epochs=3, minibatches=4, clip=0.2, gae_lambda=0.95,
        optimizer="adam", lr=3e-4, max_grad_norm=0.5, loss_reduction="mean", normalize_advantages=True,
        reward_scale=0.1,
        action_filter="mask", valid_actions="moves", valid_loss="mass", mask_join=False,
        filter_anneal_start=40, filter_anneal_end=300, filter_final=0.0,
        curriculum_start=60, curriculum_end=300, total_episodes=4000,
    ),
}


def make_config(preset: str = "paper", **overrides) -> TrainConfig:
    if preset not in PRESETS:
        raise ValueError(f"unknown preset {preset!r}; choose from {sorted(PRESETS)}")
    return dataclasses.replace(PRESETS[preset], **overrides)


def parse_overrides(pairs: tuple[str, ...] | list[str]) -> dict:
    """``KEY=VALUE`` strings to TrainConfig fields, typed like the field's default (``none``, or
    the :data:`OFF_SPELLINGS` value, for a setting that can be off); every error names the key it
    is about."""
    import difflib

    defaults = TrainConfig()
    fields = [f.name for f in dataclasses.fields(TrainConfig)]
    out: dict = {}
    for pair in pairs:
        key, sep, text = pair.partition("=")
        if not sep:
            raise ValueError(f"--set {pair!r}: expected FIELD=VALUE with a TrainConfig field")
        if key not in fields:
            close = difflib.get_close_matches(key, fields, n=1)
            raise ValueError(f"{key!r} is not a TrainConfig field{f' (did you mean {close[0]}?)' if close else ''}: "
                             "the settings are listed in docs/training.md")
        if key == "preset":  # a label of the defaults: --set would rename them, not apply them
            raise ValueError("preset is chosen with --preset, not --set")
        if key in OFF_SPELLINGS and text.lower() == "none":
            out[key] = None
            continue
        current = typed_example(defaults, key)
        if isinstance(current, bool):
            if text.lower() not in ("true", "false", "1", "0", "yes", "no"):
                raise ValueError(f"{key} expects true/false, got {text!r}")
            out[key] = text.lower() in ("true", "1", "yes")
        elif key == "teams":
            try:
                out[key] = tuple(int(v) for v in text.split(","))
            except ValueError:
                raise ValueError(f"teams expects team sizes separated by commas (16,32), got {text!r}") from None
        elif isinstance(current, (int, float)):
            try:
                out[key] = type(current)(text)
            except ValueError:
                kind = "an integer" if isinstance(current, int) else "a number"
                raise ValueError(f"{key} expects {kind}, got {text!r}") from None
        elif key == "world_sizes":  # one MIN-MAX side range per team: 40-96,64-128
            try:
                out[key] = tuple((int(lo), int(hi)) for lo, hi in (r.split("-") for r in text.split(",")))
            except ValueError:
                raise ValueError("world_sizes expects MIN-MAX side ranges, one per team (40-96,64-128), "
                                 f"got {text!r}") from None
        elif isinstance(current, tuple):
            raise ValueError(f"{key} cannot be set from the command line")
        else:
            out[key] = type(current)(text)
    return out


def train_config_from_dict(data: dict) -> TrainConfig:
    """A TrainConfig from its JSON form (a run directory's ``config.json``): lists become
    the tuples the fields hold, so the config equals the one that was written."""
    known = {f.name for f in dataclasses.fields(TrainConfig)}
    unknown = sorted(set(data) - known)
    if unknown:
        raise ValueError(f"unknown training settings: {', '.join(unknown)}")

    def tuples(value):
        return tuple(tuples(v) for v in value) if isinstance(value, list) else value

    return TrainConfig(**{key: tuples(value) for key, value in data.items()})


def load_train_config(path: str | Path) -> TrainConfig:
    return train_config_from_dict(json.loads(Path(path).read_text()))


def plain(value):
    """Tuples and lists compare equal after a JSON round trip."""
    return json.loads(json.dumps(value))
