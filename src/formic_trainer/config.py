"""Training settings: :class:`TrainConfig`, its presets and its command-line and JSON forms.

Every mode is a ``Literal`` type, checked when a config is made (``--set action_filter=mask2``
is an error naming the allowed values, not a silent fall-through to a default branch).
"""

from __future__ import annotations

import dataclasses
import functools
import json
import typing
from dataclasses import dataclass
from pathlib import Path
from typing import Literal

from formic_agent.network import NETWORK_PRESETS
from formic_world import REWARD_PRESETS, RewardConfig


@dataclass
class TrainConfig:
    preset: Literal["paper", "cpu"] = "paper"
    network: str = "paper"  # a NETWORK_PRESETS name
    seed: int = 0
    # Meta-agent environments: team size, learning agents (-1 = all), world side range.
    teams: tuple[int, ...] = (16, 24, 32, 48)
    learning_agents: int = 8
    world_sizes: tuple[tuple[int, int], ...] = ((20, 96), (20, 96), (40, 96), (64, 128))
    obstacle_range: tuple[float, float] = (0.0, 0.05)
    episode_steps: int = 512
    view_size: int = 11
    # Algorithm
    rollout_steps: int = 512  # steps per update (512 = whole episodes, as the paper)
    epochs: int = 1
    minibatches: int = 1
    clip: float = 0.0  # PPO ratio clip; 0 = plain actor-critic (the paper)
    gamma: float = 0.95
    gae_lambda: float = 1.0  # 1.0 = n-step bootstrapped returns (the paper)
    value_coef: float = 0.5
    # Train the critic on queued steps too (beyond the paper, which masks queued steps out of
    # every loss term). With the paper's lambda=1 returns the values inside a queue never enter
    # an advantage; with GAE (lambda<1, the cpu preset) every queued step's value does, with
    # weight gamma*(1-lambda), and an untrained critic reads ~0 there (measured at 128 agents:
    # -0.01 against a true return of +0.38), so a JOIN's advantage loses part of the deposit
    # that follows it. Fixed, it did not change the 128-agent food (models/formic_paper.md). The
    # policy and valid-action terms stay masked on queued steps either way.
    queued_value_loss: bool = False
    entropy_coef: float = 0.01
    valid_coef: float = 0.5
    # Valid-action loss on the JOIN logit too ("all", the paper) or on the four moves only
    # ("moves"): JOIN is valid on ~4% of steps, and fitting that base rate through the shared
    # logits suppresses JOIN before the network can recognise a queue entry (measured: food
    # collapses), while the policy gradient alone teaches when to JOIN.
    valid_actions: Literal["all", "moves"] = "all"
    # "bce": the paper's valid-action predictor (sigmoid of the logits vs the mask). "mass":
    # -log of the probability the policy's move distribution puts on valid moves. With masked
    # sampling the policy gradient never touches invalid logits, and BCE (a per-action
    # threshold at 0) left agents unable to act unmasked (measured: 59 food with the filter,
    # 3 without); "mass" trains exactly the unmasked softmax agents use at test time.
    valid_loss: Literal["bce", "mass"] = "bce"
    # The paper's valid-action BCE on the JOIN logit alone, beside valid_loss (beyond the cpu
    # preset, which leaves JOIN to the policy gradient: see valid_actions). For a trained
    # policy: at 128 agents the shipped model JOINs on 44% of the steps where a loaded agent
    # may (91% at 16 agents), and a cache-entry mark in the observation is not a valid JOIN on
    # a quarter of them (the entry cell is taken). Measured: agents then queue less, not more
    # (JOIN is valid on a few percent of steps, and the base rate wins). 0 = off.
    valid_join_coef: float = 0.0
    # With action_filter="mask": also mask JOIN when invalid (True), or let agents try JOIN
    # anywhere as at test time, where a JOIN with no queue in reach wastes the step (False).
    mask_join: bool = True
    # Filter annealing (beyond the paper; "mask" mode): each learning agent-episode is filtered
    # with a probability falling linearly from 1 at filter_anneal_start to filter_final at
    # filter_anneal_end. Unfiltered agents act as at test time while the valid-action loss still
    # teaches the filter in the states they reach, so they learn to recover from their own
    # mistakes (an always-filtered policy never visits them: measured 59 food with the filter,
    # 3 without).
    filter_anneal_start: int = 0
    filter_anneal_end: int = 0
    filter_final: float = 1.0
    init_weights: str = ""  # start the network from this checkpoint (warm start / fine-tune)
    # A moving average of the weights kept beside them (beyond the paper): after each update
    # averaged = d * averaged + (1 - d) * weights, d = weight_average (0 = off; 0.99 spans about
    # the last 100 updates). Written at every checkpoint as ``averaged.pt`` (a model for --model)
    # and carried in ``latest.pt``. At 128 agents single checkpoints eight updates apart swing
    # between 316 and 742 food (models/formic_paper.md), so the policy a run ends with is a lottery.
    weight_average: float = 0.0
    optimizer: Literal["nadam", "adam"] = "nadam"
    lr: float = 5e-6
    # Learning-rate warm-up over the first N updates of a run (beyond the paper). A fine-tune
    # from bare weights (init_weights) starts Adam with empty moments, whose first steps move
    # every weight by ~lr at once: measured, the policy's entropy rose from 0.45 to 0.8 within
    # one episode set of a crowd fine-tune. 0 = off.
    lr_warmup: int = 0
    max_grad_norm: float = 10.0
    loss_reduction: Literal["sum", "mean"] = "sum"  # "sum": gradients of all learning agents are summed (paper)
    normalize_advantages: bool = False
    reward_scale: float = 1.0
    # Team reward (beyond the paper): each agent's reward becomes (1-f)*own + f*(its world's team
    # mean). With purely individual rewards, loaded agents crowding the nest cost only the empty
    # agents they trap; sharing makes the team's throughput part of every agent's return.
    team_reward: float = 0.0
    # Imitation (beyond the paper: warm-starting from a demonstrator, DAgger style). The named
    # baseline policy runs beside the learners on the very observations they see, without
    # acting; its action is a cross-entropy target (weight imitation_coef) for the learners'
    # free agents that imitation_agents names ("loaded" or "all") within imitation_radius
    # cells (Chebyshev) of the nest centre (0: anywhere). Meant for the crowded nest, where
    # C-SAF-11's orbit keeps 128 agents flowing. "" = off.
    imitate: str = ""
    imitation_coef: float = 0.0
    imitation_agents: Literal["loaded", "all"] = "loaded"
    imitation_radius: int = 0
    # Techniques (the paper's ablation switches)
    action_filter: Literal["replace", "mask", "none"] = "replace"  # replace (paper); mask: mask invalid logits
    training_filter: Literal["paper", "reference"] = "paper"  # carrying agents' filter (SPEC §4)
    rewards: Literal["paper", "reference"] = "paper"  # a formic_world.REWARD_PRESETS name (SPEC §4)
    # Single rewards replacing the preset's (beyond the paper): "deposit=10,blocked=-0.5", fields
    # of formic_world.RewardConfig. Measured (models/formic_paper.md): with the paper's table loaded
    # agents queue up to twice as much as with the reference code's, but agents that have unloaded
    # hold the docks longer (a blocked step costs -0.05 against -0.5); the deposit's pay alone
    # (deposit=10 on the reference rewards) does not make them queue more.
    reward_overrides: str = ""
    pheromones: bool = True  # False: train (and test) without pheromones
    curriculum: bool = True
    curriculum_start: int = 5000
    curriculum_end: int = 10000
    training_start: bool = True  # some agents start in cache queues loaded (reference behaviour)
    # Run
    total_episodes: int = 24000  # environment episodes (summed over meta-agents)
    checkpoint_every: int = 1  # episode sets (one episode in every meta-agent world)
    threads: int = 1

    def __post_init__(self) -> None:
        for name, allowed in _choices().items():
            if getattr(self, name) not in allowed:
                raise ValueError(f"{name} must be one of {', '.join(map(repr, allowed))}, not {getattr(self, name)!r}")
        if self.network not in NETWORK_PRESETS:
            raise ValueError(f"network must be one of {', '.join(map(repr, NETWORK_PRESETS))}, not {self.network!r}")
        if not 0.0 <= self.weight_average < 1.0:
            raise ValueError(f"weight_average is a decay in [0, 1) (0 = off), not {self.weight_average}")
        reward_config(self)  # a bad reward_overrides fails here, not at the first episode
        if len(self.world_sizes) < len(self.teams):
            raise ValueError(f"{len(self.teams)} teams but {len(self.world_sizes)} world_sizes: give one side "
                             "range per team (--set world_sizes=40-96,64-128)")

    def to_dict(self) -> dict:
        return dataclasses.asdict(self)


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
        preset="cpu", network="cpu", learning_agents=-1,
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
    """``KEY=VALUE`` strings to TrainConfig fields, typed like the field's default."""
    defaults = TrainConfig()
    out: dict = {}
    for pair in pairs:
        key, sep, text = pair.partition("=")
        if not sep or not hasattr(defaults, key):
            raise ValueError(f"bad override {pair!r}: expected FIELD=VALUE with a TrainConfig field")
        current = getattr(defaults, key)
        if isinstance(current, bool):
            if text.lower() not in ("true", "false", "1", "0", "yes", "no"):
                raise ValueError(f"{key} expects true/false, got {text!r}")
            out[key] = text.lower() in ("true", "1", "yes")
        elif key == "teams":
            out[key] = tuple(int(v) for v in text.split(","))
        elif key == "world_sizes":  # one MIN-MAX side range per team: 40-96,64-128
            try:
                out[key] = tuple((int(lo), int(hi)) for lo, hi in (r.split("-") for r in text.split(",")))
            except ValueError:
                raise ValueError(f"world_sizes expects MIN-MAX side ranges, one per team (40-96,64-128), got {text!r}") from None
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
