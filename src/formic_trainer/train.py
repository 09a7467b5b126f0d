"""ForMIC training, top to bottom in one file (CleanRL style).

The paper's algorithm (SPEC §6): an actor-critic over whole 512-step episodes with
bootstrapped discounted returns, loss = L_pi (with entropy bonus) + 0.5 L_V + 0.5 L_valid,
queued steps masked out of every term, gradients of all learning agents summed into one
global network. Several "meta-agent" worlds step together; only ``learning_agents`` agents
per world produce gradients, the rest run the current policy. Action filtering (sample,
replace an invalid action by a random valid one, mask that step out of the value loss), the
pheromone-highway curriculum and random world sizes/obstacles per reset are all switches.

The ``cpu`` preset keeps the algorithm's losses and techniques but makes it learn in hours on
two cores: a small network, PPO-style clipped updates on 128-step chunks with GAE, Adam at a
larger learning rate, advantage normalisation, reward scaling, every agent learning, and a
curriculum scaled to the shorter run. Each change is a field below and is logged with the run.
"""

from __future__ import annotations

import dataclasses
import json
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import torch
import torch.nn.functional as F

from formic_agent.checkpoint import load_network, read_checkpoint, save_checkpoint
from formic_agent.network import N_EXTRA_INPUTS, NETWORK_PRESETS, ForMICNet, nest_features
from formic_agent.policy import AgentBatch
from formic_runtime.registry import make_policy
from formic_world import REWARD_PRESETS, Scenario, World, WorldConfig, generate_scenario
from formic_world.pheromones import curriculum_intensities


@dataclass
class TrainConfig:
    preset: str = "paper"
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
    entropy_coef: float = 0.01
    valid_coef: float = 0.5
    # Valid-action loss on the JOIN logit too ("all", the paper) or on the four moves only
    # ("moves"): JOIN is valid on ~4% of steps, and fitting that base rate through the shared
    # logits suppresses JOIN before the network can recognise a queue entry (measured: food
    # collapses), while the policy gradient alone teaches when to JOIN.
    valid_actions: str = "all"
    # "bce": the paper's valid-action predictor (sigmoid of the logits vs the mask). "mass":
    # -log of the probability the policy's move distribution puts on valid moves. With masked
    # sampling the policy gradient never touches invalid logits, and BCE (a per-action
    # threshold at 0) left agents unable to act unmasked (measured: 59 food with the filter,
    # 3 without); "mass" trains exactly the unmasked softmax agents use at test time.
    valid_loss: str = "bce"
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
    optimizer: str = "nadam"
    lr: float = 5e-6
    # Learning-rate warm-up over the first N updates of a run (beyond the paper). A fine-tune
    # from bare weights (init_weights) starts Adam with empty moments, whose first steps move
    # every weight by ~lr at once: measured, the policy's entropy rose from 0.45 to 0.8 within
    # one episode set of a crowd fine-tune. 0 = off.
    lr_warmup: int = 0
    max_grad_norm: float = 10.0
    loss_reduction: str = "sum"  # "sum": gradients of all learning agents are summed (paper)
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
    imitation_agents: str = "loaded"
    imitation_radius: int = 0
    # Techniques (the paper's ablation switches)
    action_filter: str = "replace"  # "replace" (paper) | "mask" (mask invalid logits) | "none"
    training_filter: str = "paper"  # carrying agents' filter: "paper" | "reference" (SPEC §4)
    rewards: str = "paper"  # a formic_world.REWARD_PRESETS name: "paper" | "reference" (SPEC §4)
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
        if self.rewards not in REWARD_PRESETS:
            raise ValueError(f"rewards must be one of {sorted(REWARD_PRESETS)}, not {self.rewards!r}")
        if self.training_filter not in ("paper", "reference"):
            raise ValueError(f"training_filter must be 'paper' or 'reference', not {self.training_filter!r}")
        if self.imitation_agents not in ("loaded", "all"):
            raise ValueError(f"imitation_agents must be 'loaded' or 'all', not {self.imitation_agents!r}")
        if len(self.world_sizes) < len(self.teams):
            raise ValueError(f"{len(self.teams)} teams but {len(self.world_sizes)} world_sizes: give one side "
                             "range per team (--set world_sizes=40-96,64-128)")

    def to_dict(self) -> dict:
        return dataclasses.asdict(self)


PRESETS = {
    "paper": TrainConfig(),
    "cpu": TrainConfig(
        preset="cpu",
        network="cpu",
        learning_agents=-1,
        rollout_steps=128,
        epochs=3,
        minibatches=4,
        clip=0.2,
        gae_lambda=0.95,
        optimizer="adam",
        lr=3e-4,
        max_grad_norm=0.5,
        loss_reduction="mean",
        normalize_advantages=True,
        reward_scale=0.1,
        action_filter="mask",
        valid_actions="moves",
        valid_loss="mass",
        mask_join=False,
        filter_anneal_start=40,
        filter_anneal_end=300,
        filter_final=0.0,
        curriculum_start=60,
        curriculum_end=300,
        total_episodes=4000,
    ),
}


def make_config(preset: str = "paper", **overrides) -> TrainConfig:
    if preset not in PRESETS:
        raise ValueError(f"unknown preset {preset!r}; choose from {sorted(PRESETS)}")
    return dataclasses.replace(PRESETS[preset], **overrides)


# ----------------------------------------------------------------------------- environments
def scenario_rng(cfg: TrainConfig, episode: int) -> np.random.Generator:
    """The scenario stream of a run that starts (or resumes) at global ``episode``."""
    return np.random.default_rng([cfg.seed, 3, episode])


def sample_scenarios(cfg: TrainConfig, rng: np.random.Generator,
                     episode: int) -> tuple[list[Scenario], float, float]:
    """One episode set's scenarios, one per meta-agent world (random side, obstacle density
    and seed, drawn from ``rng`` in that order), with the curriculum's pheromone intensities
    at global ``episode``. Returns (scenarios, highway intensity, deposit strength). The
    in-process trainer and the ROS world node (distributed training) both draw from here."""
    if cfg.curriculum and cfg.pheromones:
        highway, deposit = curriculum_intensities(episode, cfg.curriculum_start, cfg.curriculum_end)
    else:
        highway, deposit = 0.0, 1.0
    scenarios = []
    for team, (lo, hi) in zip(cfg.teams, cfg.world_sizes):
        side = 2 * int(rng.integers(lo // 2, hi // 2 + 1))
        config = WorldConfig(
            height=side, width=side, n_agents=team,
            obstacle_density=float(rng.uniform(*cfg.obstacle_range)),
            episode_steps=cfg.episode_steps, view_size=cfg.view_size,
            highway_intensity=highway, deposit_strength=deposit,
            pheromones_visible=cfg.pheromones, training_start=cfg.training_start,
            training_filter=cfg.training_filter, rewards=REWARD_PRESETS[cfg.rewards],
        )
        scenarios.append(generate_scenario(config, int(rng.integers(2**31))))
    return scenarios, highway, deposit


def share_rewards(rewards: np.ndarray, fraction: float) -> np.ndarray:
    """Mix one world's per-agent rewards with their mean (``team_reward``).

    Mixed in float32, as the ROS observation messages carry rewards, and returned as float64
    for the float64 reward scaling both trainers share, so distributed training stays exact.
    """
    if fraction == 0.0:
        return rewards
    team = np.asarray(rewards, dtype=np.float32)
    mixed = np.float32(1.0 - fraction) * team + np.float32(fraction) * team.mean(dtype=np.float32)
    return mixed.astype(np.float64)


class MetaAgents:
    """All training worlds, stepped together so one forward pass serves every agent."""

    def __init__(self, cfg: TrainConfig):
        self.cfg = cfg
        self.rng = np.random.default_rng([cfg.seed, 3])
        self.worlds: list[World] = []
        self.offsets = np.cumsum([0, *cfg.teams])
        self.n_agents = int(self.offsets[-1])
        learners = [
            np.arange(o, o + (t if cfg.learning_agents < 0 else min(cfg.learning_agents, t)))
            for o, t in zip(self.offsets[:-1], cfg.teams)
        ]
        self.learners = np.concatenate(learners)
        self.experts: list = []  # one demonstrator per world (cfg.imitate)
        self._seen: list[tuple[np.ndarray, np.ndarray]] = []  # each world's last (observations, valid)

    def reset(self, episode: int) -> None:
        """New scenarios for every world; curriculum intensities from the global episode."""
        scenarios, self.highway, self.deposit = sample_scenarios(self.cfg, self.rng, episode)
        self.worlds = [World(scenario) for scenario in scenarios]
        if self.cfg.imitate:
            self.experts = [make_policy(self.cfg.imitate) for _ in scenarios]
            for expert, scenario in zip(self.experts, scenarios):
                expert.reset(scenario.config.n_agents, scenario.seed)

    def observe(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """(obs, extra, env-valid mask, training mask, queued) for every agent of every world."""
        obs, extra, valid, train, queued = [], [], [], [], []
        self._seen = []
        for w in self.worlds:
            obs.append(w.observer.observe())
            v = w.action_mask()
            valid.append(v)
            self._seen.append((obs[-1], v))
            train.append(w.training_action_mask(v))
            queued.append(w.queued)
            extra.append(nest_features(w.pos, w.loads, w.grid.shape))
        return (np.concatenate(obs), np.concatenate(extra), np.concatenate(valid),
                np.concatenate(train), np.concatenate(queued))

    def demonstrations(self) -> tuple[np.ndarray, np.ndarray]:
        """(expert action, whether it is an imitation target) for every agent of every world,
        from the last observations; the experts must see every step to keep their state."""
        cfg, targets, wanted = self.cfg, [], []
        for w, expert, (obs, valid) in zip(self.worlds, self.experts, self._seen):
            targets.append(expert.act(AgentBatch.from_world(w, observations=obs, action_mask=valid)))
            near = np.abs(w.pos - (np.array(w.grid.shape) / 2 - 0.5)).max(axis=1) <= (cfg.imitation_radius or np.inf)
            who = w.carrying if cfg.imitation_agents == "loaded" else np.ones(len(w.pos), bool)
            wanted.append(near & who & ~w.queued)
        return np.concatenate(targets), np.concatenate(wanted)

    def step(self, actions: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        rewards, food = [], []
        for w, lo, hi in zip(self.worlds, self.offsets[:-1], self.offsets[1:]):
            result = w.step(actions[lo:hi])
            rewards.append(share_rewards(result.rewards, self.cfg.team_reward))
            food.append(result.food)
        return np.concatenate(rewards), np.array(food)


# ----------------------------------------------------------------------------- losses
def policy_losses(
    net: ForMICNet, cfg: TrainConfig, batch: dict[str, torch.Tensor]
) -> dict[str, torch.Tensor]:
    """All loss terms over a batch of agent sequences (T, B, ...) from their initial state."""
    logits, values, _ = net(batch["obs"], (batch["h0"], batch["c0"]), batch["extra"])
    if cfg.action_filter == "mask":
        allowed = batch["sample_mask"] if "sample_mask" in batch else sampling_mask(cfg, batch["train_mask"])
        logits_for_pi = logits.masked_fill(~allowed, -1e9)
    else:
        logits_for_pi = logits
    log_probs = torch.log_softmax(logits_for_pi, dim=-1)
    logp = log_probs.gather(-1, batch["actions"].unsqueeze(-1)).squeeze(-1)
    entropy = -(log_probs.exp() * log_probs).sum(-1)
    loss_mask = batch["loss_mask"]
    value_mask = loss_mask * batch["value_mask"]
    adv = batch["advantages"]
    if cfg.clip > 0:
        ratio = torch.exp(logp - batch["logp"])
        pg = -torch.min(ratio * adv, torch.clamp(ratio, 1 - cfg.clip, 1 + cfg.clip) * adv)
    else:
        pg = -logp * adv
    value_err = 0.5 * (values - batch["returns"]) ** 2
    if cfg.valid_loss == "mass":
        move_logp = torch.log_softmax(logits[..., :4], dim=-1).masked_fill(~batch["train_mask"][..., :4], -1e9)
        valid_term = -torch.logsumexp(move_logp, dim=-1).clamp(max=1e8)
    else:
        valid_term = F.binary_cross_entropy_with_logits(
            logits, batch["train_mask"].float(), reduction="none"
        )
        valid_term = valid_term[..., :4].sum(-1) if cfg.valid_actions == "moves" else valid_term.sum(-1)

    def reduce(x: torch.Tensor, mask: torch.Tensor) -> torch.Tensor:
        total = (x * mask).sum()
        return total if cfg.loss_reduction == "sum" else total / mask.sum().clamp(min=1.0)

    terms = {
        "policy": reduce(pg, loss_mask),
        "value": reduce(value_err, value_mask),
        "entropy": reduce(entropy, loss_mask),
        "valid": reduce(valid_term * batch["any_valid"], loss_mask),
    }
    terms["loss"] = (
        terms["policy"] - cfg.entropy_coef * terms["entropy"]
        + cfg.value_coef * terms["value"] + cfg.valid_coef * terms["valid"]
    )
    if "expert_actions" in batch:  # the agents' own unmasked policy, as it acts at test time
        own = torch.log_softmax(logits, dim=-1)
        imitation_mask = batch["imitation_mask"]
        terms["imitation"] = reduce(-own.gather(-1, batch["expert_actions"].unsqueeze(-1)).squeeze(-1), imitation_mask)
        terms["loss"] = terms["loss"] + cfg.imitation_coef * terms["imitation"]
        with torch.no_grad():
            agree = (logits.argmax(-1) == batch["expert_actions"]).float()
            terms["expert_agreement"] = (agree * imitation_mask).sum() / imitation_mask.sum().clamp(min=1.0)
    with torch.no_grad():
        predicted = torch.sigmoid(logits) > 0.5
        agree = (predicted == batch["train_mask"])[..., :4].all(-1).float()
        terms["valid_accuracy"] = (agree * loss_mask).sum() / loss_mask.sum().clamp(min=1.0)
        if cfg.clip > 0:
            terms["clip_fraction"] = (((ratio - 1).abs() > cfg.clip).float() * loss_mask).sum() / loss_mask.sum().clamp(min=1.0)
    return terms


def advantages_and_returns(cfg: TrainConfig, rewards, values, next_value) -> tuple[np.ndarray, np.ndarray]:
    """GAE over a chunk (T, B); lambda=1 gives the paper's bootstrapped discounted returns.
    An episode is truncated by time, so the last step always bootstraps from next_value."""
    steps = rewards.shape[0]
    adv = np.zeros_like(rewards)
    last = np.zeros(rewards.shape[1], dtype=np.float32)
    for t in reversed(range(steps)):
        nxt = next_value if t == steps - 1 else values[t + 1]
        delta = rewards[t] + cfg.gamma * nxt - values[t]
        last = delta + cfg.gamma * cfg.gae_lambda * last
        adv[t] = last
    return adv, adv + values


def update(net: ForMICNet, optimizer: torch.optim.Optimizer, cfg: TrainConfig, data: dict[str, np.ndarray],
           rng: np.random.Generator) -> dict[str, float]:
    """One update from a rollout chunk: the same function serves the in-process trainer and
    the ROS trainer node. ``data`` arrays are time-major (T, B, ...)."""
    adv, returns = advantages_and_returns(cfg, data["rewards"], data["values"], data["next_value"])
    tensors = {
        "obs": torch.from_numpy(data["obs"]),
        "extra": torch.from_numpy(data["extra"]),
        "actions": torch.from_numpy(data["actions"]).long(),
        "logp": torch.from_numpy(data["logp"]),
        "train_mask": torch.from_numpy(data["train_mask"]),
        **({"sample_mask": torch.from_numpy(data["sample_mask"])} if "sample_mask" in data else {}),
        "any_valid": torch.from_numpy(data["train_mask"][..., :4].any(-1).astype(np.float32)),
        "loss_mask": torch.from_numpy(data["loss_mask"]).float(),
        "value_mask": torch.from_numpy(data["value_mask"]).float(),
        "returns": torch.from_numpy(returns.astype(np.float32)),
        "h0": torch.from_numpy(data["h0"]),
        "c0": torch.from_numpy(data["c0"]),
    }
    if "expert_actions" in data:
        tensors["expert_actions"] = torch.from_numpy(data["expert_actions"]).long()
        tensors["imitation_mask"] = torch.from_numpy(data["imitation_mask"]).float()
    adv_t = torch.from_numpy(adv.astype(np.float32))
    if cfg.normalize_advantages:
        m = tensors["loss_mask"]
        mean = (adv_t * m).sum() / m.sum().clamp(min=1)
        std = torch.sqrt((((adv_t - mean) ** 2) * m).sum() / m.sum().clamp(min=1)) + 1e-8
        adv_t = (adv_t - mean) / std
    tensors["advantages"] = adv_t
    n_seq = tensors["obs"].shape[1]
    stats: dict[str, list[float]] = {}
    for _ in range(cfg.epochs):
        order = rng.permutation(n_seq)
        for chunk in np.array_split(order, cfg.minibatches):
            idx = torch.from_numpy(chunk)
            batch = {k: v[:, idx] for k, v in tensors.items()}
            terms = policy_losses(net, cfg, batch)
            optimizer.zero_grad()
            terms["loss"].backward()
            grad_norm = torch.nn.utils.clip_grad_norm_(net.parameters(), cfg.max_grad_norm)
            optimizer.step()
            terms["grad_norm"] = grad_norm
            for k, v in terms.items():
                stats.setdefault(k, []).append(float(v.detach()) if torch.is_tensor(v) else float(v))
    return {k: float(np.mean(v)) for k, v in stats.items()}


def set_learning_rate(optimizer: torch.optim.Optimizer, cfg: TrainConfig, updates: int) -> None:
    """The learning rate of update number ``updates`` (0-based): ``lr``, ramped up linearly
    over the first ``lr_warmup`` updates."""
    scale = min(1.0, (updates + 1) / cfg.lr_warmup) if cfg.lr_warmup > 0 else 1.0
    for group in optimizer.param_groups:
        group["lr"] = cfg.lr * scale


def make_optimizer(net: ForMICNet, cfg: TrainConfig) -> torch.optim.Optimizer:
    if cfg.optimizer == "nadam":
        return torch.optim.NAdam(net.parameters(), lr=cfg.lr)
    if cfg.optimizer == "adam":
        return torch.optim.Adam(net.parameters(), lr=cfg.lr, eps=1e-5)
    raise ValueError(f"unknown optimizer {cfg.optimizer!r}")


# ----------------------------------------------------------------------------- rollouts
@dataclass
class Rollout:
    """A chunk of experience from the learning agents, time-major (T, B, ...)."""

    arrays: dict[str, np.ndarray] = field(default_factory=dict)


def filter_probability(cfg: TrainConfig, episode: int) -> float:
    """Probability that an agent-episode acts under the training filter."""
    start, end = cfg.filter_anneal_start, cfg.filter_anneal_end
    if end <= start:
        return 1.0
    fraction = min(max((episode - start) / (end - start), 0.0), 1.0)
    return 1.0 + fraction * (cfg.filter_final - 1.0)


def sampling_mask(cfg: TrainConfig, train_mask):
    """Actions the behaviour policy may sample in "mask" mode (numpy or torch)."""
    if cfg.mask_join:
        return train_mask
    allowed = train_mask.clone() if isinstance(train_mask, torch.Tensor) else train_mask.copy()
    allowed[..., 4] = True
    return allowed


def select_actions(cfg: TrainConfig, logits: torch.Tensor, valid: np.ndarray, train_mask: np.ndarray,
                   generator: torch.Generator, rng: np.random.Generator,
                   sample_mask: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Sample actions under the training filter. Returns (actions, log-probs, value_mask).
    In "mask" mode ``sample_mask`` (default: ``sampling_mask``) says what may be sampled."""
    if cfg.action_filter == "mask":
        allowed = sampling_mask(cfg, train_mask) if sample_mask is None else sample_mask
        masked = logits.masked_fill(~torch.from_numpy(allowed), -1e9)
        probs = torch.softmax(masked, -1)
        actions = torch.multinomial(probs, 1, generator=generator)[:, 0]
        logp = torch.log_softmax(masked, -1).gather(-1, actions[:, None])[:, 0]
        return actions.numpy(), logp.numpy(), np.ones(len(actions), dtype=np.float32)
    probs = torch.softmax(logits, -1)
    actions = torch.multinomial(probs, 1, generator=generator)[:, 0].numpy().copy()
    value_mask = np.ones(len(actions), dtype=np.float32)
    if cfg.action_filter == "replace":
        rows = np.arange(len(actions))
        invalid = ~train_mask[rows, actions] & train_mask.any(1)
        for i in np.flatnonzero(invalid):
            actions[i] = rng.choice(np.flatnonzero(train_mask[i]))
        value_mask[invalid] = 0.0
    logp = torch.log_softmax(logits, -1).gather(-1, torch.from_numpy(actions)[:, None])[:, 0]
    return actions, logp.numpy(), value_mask


class Trainer:
    def __init__(self, cfg: TrainConfig, run_dir: Path, resume: bool = True, log=print):
        self.cfg = cfg
        self.run_dir = Path(run_dir)
        self.run_dir.mkdir(parents=True, exist_ok=True)
        self.log = log
        torch.set_num_threads(cfg.threads)
        torch.manual_seed(cfg.seed)
        self.net = ForMICNet(dataclasses.replace(NETWORK_PRESETS[cfg.network], view_size=cfg.view_size))
        self.net = self.net.to(memory_format=torch.channels_last)
        self.optimizer = make_optimizer(self.net, cfg)
        self.episode = 0  # global environment episodes finished
        self.episode_sets = 0  # in this process
        self.updates = 0
        self.env_steps = 0
        self.seconds = 0.0
        self.generator = torch.Generator().manual_seed(cfg.seed)
        self.rng = np.random.default_rng([cfg.seed, 5])
        latest = self.run_dir / "latest.pt"
        if resume and latest.exists():
            self._resume(latest)
        elif cfg.init_weights:
            net, _ = load_network(cfg.init_weights)
            self.net.load_state_dict(net.state_dict())
            self.log(f"network initialised from {cfg.init_weights}")
        (self.run_dir / "config.json").write_text(json.dumps(cfg.to_dict(), indent=2))
        self.envs = MetaAgents(cfg)
        self.envs.rng = scenario_rng(cfg, self.episode)
        from torch.utils.tensorboard import SummaryWriter

        self.writer = SummaryWriter(str(self.run_dir / "tb"))
        self.writer.add_text("config", json.dumps(cfg.to_dict(), indent=2))

    def _resume(self, path: Path) -> None:
        payload = read_checkpoint(path)
        stored = payload.get("train_config", {})
        ignored = {"total_episodes", "threads", "checkpoint_every", "init_weights"}
        changed = sorted(k for k, v in self.cfg.to_dict().items()
                         if k not in ignored and k in stored and _plain(stored[k]) != _plain(v))
        if changed:
            raise ValueError(
                f"{path} was trained with different settings ({', '.join(changed)}); "
                "use the same settings, a new --run-dir, or --fresh"
            )
        self.net.load_state_dict(payload["state_dict"])
        self.optimizer.load_state_dict(payload["optimizer"])
        progress = payload["progress"]
        self.episode, self.updates = progress["episode"], progress["updates"]
        self.env_steps, self.seconds = progress["env_steps"], progress["seconds"]
        self.generator.manual_seed(self.cfg.seed + self.updates)
        self.rng = np.random.default_rng([self.cfg.seed, 5, self.updates])
        self.log(f"resumed from {path}: episode {self.episode}, update {self.updates}")

    def save(self, name: str = "latest.pt") -> None:
        save_checkpoint(
            self.run_dir / name, self.net,
            optimizer=self.optimizer.state_dict(),
            train_config=self.cfg.to_dict(),
            progress={"episode": self.episode, "updates": self.updates, "env_steps": self.env_steps,
                      "seconds": self.seconds},
        )

    def run_episode_set(self) -> dict[str, float]:
        """Every meta-agent world plays one episode; updates happen every rollout chunk."""
        cfg, envs, net = self.cfg, self.envs, self.net
        envs.reset(self.episode)
        n, learners = envs.n_agents, envs.learners
        unfiltered = self.rng.random(n) >= filter_probability(cfg, self.episode)
        h = torch.zeros(1, n, net.config.rnn)
        c = torch.zeros(1, n, net.config.rnn)
        food = np.zeros(len(envs.worlds))
        stats_acc: dict[str, list[float]] = {}
        valid_rate = []
        obs, extra, valid, train_mask, queued = envs.observe()
        for _chunk_start in range(0, cfg.episode_steps, cfg.rollout_steps):
            T = min(cfg.rollout_steps, cfg.episode_steps - _chunk_start)
            buf = {
                "obs": np.zeros((T, len(learners), *obs.shape[1:]), np.float32),
                "extra": np.zeros((T, len(learners), N_EXTRA_INPUTS), np.float32),
                "actions": np.zeros((T, len(learners)), np.int64),
                "logp": np.zeros((T, len(learners)), np.float32),
                "values": np.zeros((T, len(learners)), np.float32),
                "rewards": np.zeros((T, len(learners)), np.float32),
                "train_mask": np.zeros((T, len(learners), 5), bool),
                "sample_mask": np.zeros((T, len(learners), 5), bool),
                "loss_mask": np.zeros((T, len(learners)), np.float32),
                "value_mask": np.zeros((T, len(learners)), np.float32),
                "h0": h[:, learners].numpy().copy(),
                "c0": c[:, learners].numpy().copy(),
            }
            if cfg.imitate:
                buf["expert_actions"] = np.zeros((T, len(learners)), np.int64)
                buf["imitation_mask"] = np.zeros((T, len(learners)), np.float32)
            for t in range(T):
                with torch.no_grad():
                    logits, values, (h, c) = net(
                        torch.from_numpy(obs)[None], (h, c), torch.from_numpy(extra)[None]
                    )
                logits, values = logits[0], values[0]
                allowed = sampling_mask(cfg, train_mask)
                allowed[unfiltered] = True
                actions, logp, value_mask = select_actions(cfg, logits, valid, train_mask, self.generator,
                                                           self.rng, sample_mask=allowed)
                valid_rate.append(float(valid[np.arange(n), actions][~queued].mean()) if (~queued).any() else 1.0)
                buf["obs"][t] = obs[learners]
                buf["extra"][t] = extra[learners]
                buf["actions"][t] = actions[learners]
                buf["logp"][t] = logp[learners]
                buf["values"][t] = values.numpy()[learners]
                buf["train_mask"][t] = train_mask[learners]
                buf["sample_mask"][t] = allowed[learners]
                buf["loss_mask"][t] = ~queued[learners]
                buf["value_mask"][t] = value_mask[learners]
                if cfg.imitate:
                    expert_actions, wanted = envs.demonstrations()
                    buf["expert_actions"][t] = expert_actions[learners]
                    buf["imitation_mask"][t] = wanted[learners]
                rewards, step_food = envs.step(actions)
                food += step_food
                buf["rewards"][t] = rewards[learners] * cfg.reward_scale
                obs, extra, valid, train_mask, queued = envs.observe()
            with torch.no_grad():
                _, next_values, _ = net(torch.from_numpy(obs)[None], (h, c), torch.from_numpy(extra)[None])
            buf["next_value"] = next_values[0].numpy()[learners]
            self.env_steps += T * n
            set_learning_rate(self.optimizer, cfg, self.updates)
            stats = update(net, self.optimizer, cfg, buf, self.rng)
            self.updates += 1
            for k, v in stats.items():
                stats_acc.setdefault(k, []).append(v)
        self.episode += len(envs.worlds)
        result = {k: float(np.mean(v)) for k, v in stats_acc.items()}
        result["food_mean"] = float(food.mean())
        for i, f in enumerate(food):
            result[f"food_env{i}"] = float(f)
        result["valid_rate"] = float(np.mean(valid_rate))
        result["highway_intensity"] = envs.highway
        result["deposit_strength"] = envs.deposit
        result["filter_probability"] = filter_probability(cfg, self.episode - len(envs.worlds))
        return result

    def train(self, episodes: int | None = None, minutes: float | None = None) -> None:
        target = self.cfg.total_episodes if episodes is None else self.episode + episodes
        deadline = None if minutes is None else time.time() + 60 * minutes
        while self.episode < target and (deadline is None or time.time() < deadline):
            t0 = time.time()
            stats = self.run_episode_set()
            self.seconds += time.time() - t0
            for k, v in stats.items():
                self.writer.add_scalar(f"train/{k}", v, self.episode)
            self.writer.add_scalar("train/agent_steps_per_s", self.env_steps / max(self.seconds, 1e-9), self.episode)
            self.writer.flush()
            sps = self.env_steps / max(self.seconds, 1e-9)
            per_env = " ".join(f"{stats[f'food_env{i}']:.0f}" for i in range(len(self.cfg.teams)))
            imitation = (f"imit {stats['imitation']:.3f} agree {stats['expert_agreement']:.2f} | "
                         if "imitation" in stats else "")
            self.log(
                f"ep {self.episode:6d} | food {stats['food_mean']:6.1f} "
                f"({per_env}) | "
                f"loss {stats['loss']:.3f} pi {stats['policy']:.3f} v {stats['value']:.3f} "
                f"ent {stats['entropy']:.3f} valid {stats['valid_accuracy']:.3f} act-ok {stats['valid_rate']:.2f} | "
                f"{imitation}I_h {stats['highway_intensity']:.2f} | {sps:,.0f} agent-steps/s | {self.seconds / 60:.1f} min"
            )
            self.episode_sets += 1
            if self.episode_sets % self.cfg.checkpoint_every == 0:
                self.save()
        self.save()
        self.writer.close()


def export_model(checkpoint: Path, out: Path) -> None:
    """A small shipped model: weights and configuration only (no optimiser state)."""
    net, payload = load_network(checkpoint)
    save_checkpoint(out, net, train_config=payload.get("train_config", {}), progress=payload.get("progress", {}))



def _plain(value):
    """Tuples and lists compare equal after a JSON round trip."""
    return json.loads(json.dumps(value))


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
