"""The algorithm (SPEC §6: actor-critic, loss = L_pi (entropy bonus) + 0.5 L_V + 0.5 L_valid,
queued steps masked out; the ``cpu`` preset adds PPO clipping and GAE): network, sampling
mask, loss terms, GAE, one update (in fp32, or its forward+backward under bf16 autocast where the
CPU has native bf16), the optimiser and its learning rate."""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from pathlib import Path

import numpy as np
import torch
import torch.nn.functional as F

from formic_agent.inputs import NETWORK_PRESETS

from formic_agent.network import ForMICNet
from formic_world.errors import InputError

from .config import TrainConfig
from .rollout import Rollout


def training_network(cfg: TrainConfig) -> ForMICNet:
    """The network as training builds it (channels-last memory format: the same format gives
    the same arithmetic, so a learning host acts bit for bit as the in-process actor)."""
    config = dataclasses.replace(NETWORK_PRESETS[cfg.network], view_size=cfg.view_size)
    return ForMICNet(config).to(memory_format=torch.channels_last)


def sampling_mask(cfg: TrainConfig, train_mask: np.ndarray) -> np.ndarray:
    """Actions the behaviour policy may sample in "mask" mode: a new array, which the actor
    widens for unfiltered agents without touching the valid-action target."""
    allowed = train_mask.copy()
    if not cfg.mask_join:
        allowed[..., 4] = True
    return allowed


def masked_mean(x: torch.Tensor, mask: torch.Tensor) -> torch.Tensor:
    """The mean of ``x`` over the entries ``mask`` weights (0 when it weights none)."""
    return (x * mask).sum() / mask.sum().clamp(min=1.0)


def policy_losses(net: ForMICNet, cfg: TrainConfig,
                  batch: dict[str, torch.Tensor]) -> dict[str, torch.Tensor]:
    """All loss terms over a batch of agent sequences (T, B, ...) from their initial state."""
    logits, values, _ = net(batch["observations"], (batch["h0"], batch["c0"]), batch["extra_inputs"])
    logits_for_pi = logits
    if cfg.action_filter == "mask":
        logits_for_pi = logits.masked_fill(~batch["sample_mask"], -1e9)
    log_probs = torch.log_softmax(logits_for_pi, dim=-1)
    logp = log_probs.gather(-1, batch["actions"].unsqueeze(-1)).squeeze(-1)
    entropy = -(log_probs.exp() * log_probs).sum(-1)
    loss_mask = batch["loss_mask"]
    value_mask = batch["value_mask"] if cfg.queued_value_loss else loss_mask * batch["value_mask"]
    adv = batch["advantages"]
    if cfg.clip is not None:
        ratio = torch.exp(logp - batch["logprobs"])
        pg = -torch.min(ratio * adv, torch.clamp(ratio, 1 - cfg.clip, 1 + cfg.clip) * adv)
    else:
        pg = -logp * adv
    value_err = 0.5 * (values - batch["returns"]) ** 2
    if cfg.valid_loss == "mass":
        move_logp = torch.log_softmax(logits[..., :4], dim=-1).masked_fill(~batch["train_mask"][..., :4], -1e9)
        valid_term = -torch.logsumexp(move_logp, dim=-1).clamp(max=1e8)
    else:
        valid_term = F.binary_cross_entropy_with_logits(logits, batch["train_mask"].float(), reduction="none")
        valid_term = valid_term[..., :4].sum(-1) if cfg.valid_actions == "moves" else valid_term.sum(-1)

    def reduce(x: torch.Tensor, mask: torch.Tensor) -> torch.Tensor:
        return (x * mask).sum() if cfg.loss_reduction == "sum" else masked_mean(x, mask)

    terms = {
        "policy": reduce(pg, loss_mask),
        "value": reduce(value_err, value_mask),
        "entropy": reduce(entropy, loss_mask),
        "valid": reduce(valid_term * batch["any_valid"], loss_mask),
    }
    terms["loss"] = (terms["policy"] - cfg.entropy_coef * terms["entropy"]
                     + cfg.value_coef * terms["value"] + cfg.valid_coef * terms["valid"])
    if cfg.valid_join_coef > 0:
        join_valid = batch["train_mask"][..., 4].float()
        terms["valid_join"] = reduce(F.binary_cross_entropy_with_logits(logits[..., 4], join_valid, reduction="none"),
                                     loss_mask)
        terms["loss"] = terms["loss"] + cfg.valid_join_coef * terms["valid_join"]
    if "expert_actions" in batch:  # the agents' own unmasked policy, as it acts at test time
        own = torch.log_softmax(logits, dim=-1).gather(-1, batch["expert_actions"].unsqueeze(-1)).squeeze(-1)
        terms["imitation"] = reduce(-own, batch["imitation_mask"])
        terms["loss"] = terms["loss"] + cfg.imitation_coef * terms["imitation"]
        with torch.no_grad():
            agree = (logits.argmax(-1) == batch["expert_actions"]).float()
            terms["expert_agreement"] = masked_mean(agree, batch["imitation_mask"])
    with torch.no_grad():
        predicted = torch.sigmoid(logits) > 0.5
        agree = (predicted == batch["train_mask"])[..., :4].all(-1).float()
        terms["valid_accuracy"] = masked_mean(agree, loss_mask)
        if cfg.clip is not None:
            terms["clip_fraction"] = masked_mean(((ratio - 1).abs() > cfg.clip).float(), loss_mask)
        # KL(behaviour || current), the low-variance estimator (r - 1) - log r (Schulman's k3)
        log_ratio = logp - batch["logprobs"]
        terms["approx_kl"] = masked_mean(torch.expm1(log_ratio) - log_ratio, loss_mask)
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


def update_tensors(cfg: TrainConfig, rollout: Rollout) -> dict[str, torch.Tensor]:
    """A rollout as the loss reads it: its T acting frames, masks as floats, and the
    (normalised) advantages and returns of its scaled rewards."""
    steps = rollout.steps
    rewards = scale_rewards(rollout.rewards, cfg.reward_scale)
    adv, returns = advantages_and_returns(cfg, rewards, rollout.values, rollout.next_value)
    tensors = {
        "observations": torch.from_numpy(rollout.observations[:steps]),
        "extra_inputs": torch.from_numpy(rollout.extra_inputs[:steps]),
        "actions": torch.from_numpy(rollout.actions).long(),
        "logprobs": torch.from_numpy(rollout.logprobs),
        "train_mask": torch.from_numpy(rollout.train_mask),
        "sample_mask": torch.from_numpy(rollout.sample_mask),
        "any_valid": torch.from_numpy(rollout.train_mask[..., :4].any(-1).astype(np.float32)),
        "loss_mask": torch.from_numpy(rollout.loss_mask).float(),
        "value_mask": torch.from_numpy(rollout.value_mask).float(),
        "returns": torch.from_numpy(returns.astype(np.float32)),
        "h0": torch.from_numpy(rollout.h0),
        "c0": torch.from_numpy(rollout.c0),
    }
    if rollout.expert_actions is not None:
        tensors["expert_actions"] = torch.from_numpy(rollout.expert_actions).long()
        tensors["imitation_mask"] = torch.from_numpy(rollout.imitation_mask).float()
    adv_t = torch.from_numpy(adv.astype(np.float32))
    if cfg.normalize_advantages:
        m = tensors["loss_mask"]
        mean = masked_mean(adv_t, m)
        adv_t = (adv_t - mean) / (torch.sqrt(masked_mean((adv_t - mean) ** 2, m)) + 1e-8)
    tensors["advantages"] = adv_t
    return tensors


def update(net: ForMICNet, optimizer: torch.optim.Optimizer, cfg: TrainConfig, rollout: Rollout,
           rng: np.random.Generator) -> dict[str, float]:
    """One update from a rollout: the same function serves the in-process trainer and the ROS
    trainer node. ``rng`` permutes the agent sequences into minibatches. With ``target_kl`` the
    update stops (its remaining minibatches and epochs) at the first minibatch whose approx_kl
    exceeds 1.5 x target_kl, before stepping on it (Stable-Baselines3's rule); the stats hold
    that minibatch's terms too, and ``update_fraction``: the minibatch steps taken / planned."""
    tensors = update_tensors(cfg, rollout)
    n_seq = tensors["observations"].shape[1]
    n_batches = min(cfg.minibatches, n_seq)  # fewer learners than minibatches: one each
    stats: dict[str, list[float]] = {}
    steps, stopped = 0, False
    for _ in range(cfg.epochs):
        order = rng.permutation(n_seq)
        for chunk in np.array_split(order, n_batches):
            idx = torch.from_numpy(chunk)
            batch = {k: v[:, idx] for k, v in tensors.items()}
            with torch.autocast("cpu", dtype=torch.bfloat16, enabled=cfg.update_precision == "bf16"):
                terms = policy_losses(net, cfg, batch)
            stopped = cfg.target_kl is not None and float(terms["approx_kl"]) > 1.5 * cfg.target_kl
            if not stopped:
                optimizer.zero_grad()
                terms["loss"].backward()
                terms["grad_norm"] = torch.nn.utils.clip_grad_norm_(net.parameters(), cfg.max_grad_norm)
                optimizer.step()
                steps += 1
            for k, v in terms.items():  # every term is a tensor
                stats.setdefault(k, []).append(float(v.detach()))
            if stopped:
                break
        if stopped:
            break
    return {k: float(np.mean(v)) for k, v in stats.items()} | {"update_fraction": steps / (cfg.epochs * n_batches)}


# CPU flags of the instructions that make bf16 matrix products fast (Intel AMX, AVX-512 BF16);
# without them bf16 is emulated, slower than fp32
BF16_FLAGS = frozenset({"amx_bf16", "avx512_bf16"})


def cpu_flags(cpuinfo: Path = Path("/proc/cpuinfo")) -> frozenset[str]:
    """The first CPU's feature flags as Linux lists them (empty where the file or line is missing)."""
    try:
        text = cpuinfo.read_text()
    except OSError:
        return frozenset()
    line = next((line for line in text.splitlines() if line.startswith("flags")), "")
    return frozenset(line.partition(":")[2].split())


def check_update_precision(cfg: TrainConfig, flags: Callable[[], frozenset[str]] = cpu_flags) -> None:
    """Refuse ``update_precision = "bf16"`` on a CPU without native bf16 arithmetic (``flags``
    reads the CPU's feature flags)."""
    if cfg.update_precision == "bf16" and not BF16_FLAGS & flags():
        raise InputError("update_precision 'bf16' needs a CPU with amx_bf16 or avx512_bf16 (not in this CPU's "
                         "/proc/cpuinfo flags): use 'fp32'")


def set_learning_rate(optimizer: torch.optim.Optimizer, cfg: TrainConfig, updates: int, factor: float = 1.0) -> None:
    """The learning rate of update number ``updates`` (0-based): ``lr`` times ``factor`` (the
    fall guard's), ramped up linearly over the first ``lr_warmup`` updates."""
    scale = min(1.0, (updates + 1) / cfg.lr_warmup) if cfg.lr_warmup > 0 else 1.0
    for group in optimizer.param_groups:
        group["lr"] = cfg.lr * scale * factor


def make_optimizer(net: ForMICNet, cfg: TrainConfig) -> torch.optim.Optimizer:
    if cfg.optimizer == "nadam":
        return torch.optim.NAdam(net.parameters(), lr=cfg.lr)
    if cfg.optimizer == "adam":
        return torch.optim.Adam(net.parameters(), lr=cfg.lr, eps=1e-5)
    raise ValueError(f"unknown optimizer {cfg.optimizer!r}")  # TrainConfig checks it


def scale_rewards(rewards: np.ndarray, scale: float) -> np.ndarray:
    """The reward scaling, in float64 from the float32 rewards a rollout carries."""
    return (np.asarray(rewards, dtype=np.float32).astype(np.float64) * scale).astype(np.float32)

