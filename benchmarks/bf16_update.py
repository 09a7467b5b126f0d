#!/usr/bin/env python3
"""The PPO update in fp32 against bf16 autocast (``update_precision``), and acting in both.

Times one update step of the ``cpu-feedback`` network as ``formic_trainer.algorithm.update``
takes it (the loss terms' forward pass, backward pass, gradient clipping, Adam step) on a
minibatch of 64 steps x 64 agents (4,096 frames), and one acting forward pass on 256 frames,
each in fp32 and under ``torch.autocast("cpu", dtype=torch.bfloat16)`` (acting on the eager
layers, which autocast reaches, and in fp32 also as the actor acts, on oneDNN's blocked layout),
at 1 and 2 torch threads: the median of 3 rounds of 5 calls each (after 2 warm-up calls). The inputs are random
(the arithmetic does not depend on them). bf16 is fast only where the CPU has AMX or AVX-512
BF16; on another CPU the bf16 rows are skipped:

    .venv/bin/python benchmarks/bf16_update.py --threads 1 2

Run it on a quiet machine.
"""

from __future__ import annotations

import argparse
import statistics
import time
from contextlib import nullcontext

import torch

from formic_agent.inputs import N_EXTRA_INPUTS
from formic_trainer.algorithm import BF16_FLAGS, cpu_flags, make_optimizer, policy_losses, training_network
from formic_trainer.config import make_config

PRECISIONS = ("fp32", "bf16")


def update_batch(net, steps: int, agents: int, view: int) -> dict[str, torch.Tensor]:
    """A random minibatch shaped as ``update_tensors`` makes one (every step a learning step)."""
    h0, c0 = net.initial_state(agents)
    ones = torch.ones(steps, agents)
    return {
        "observations": torch.rand(steps, agents, 8, view, view),
        "extra_inputs": torch.rand(steps, agents, N_EXTRA_INPUTS),
        "actions": torch.randint(0, 5, (steps, agents)),
        "logprobs": torch.full((steps, agents), -1.6),
        "train_mask": torch.rand(steps, agents, 5) > 0.3,
        "sample_mask": torch.ones(steps, agents, 5, dtype=torch.bool),
        "any_valid": ones, "loss_mask": ones, "value_mask": ones,
        "returns": torch.randn(steps, agents), "advantages": torch.randn(steps, agents),
        "h0": h0, "c0": c0,
    }


def median_ms(call, rounds: int = 3, calls: int = 5, warmup: int = 2) -> float:
    """The median over ``rounds`` of the mean milliseconds per call over ``calls`` calls."""
    for _ in range(warmup):
        call()
    means = []
    for _ in range(rounds):
        started = time.perf_counter()
        for _ in range(calls):
            call()
        means.append(1000 * (time.perf_counter() - started) / calls)
    return statistics.median(means)


def measure(precision: str, threads: int, steps: int, agents: int, acting_frames: int) -> dict:
    torch.set_num_threads(threads)
    torch.manual_seed(0)
    cfg = make_config("cpu", network="cpu-feedback", update_precision=precision)
    net = training_network(cfg)
    optimizer = make_optimizer(net, cfg)
    batch = update_batch(net, steps, agents, cfg.view_size)

    def autocast():
        return torch.autocast("cpu", dtype=torch.bfloat16) if precision == "bf16" else nullcontext()

    def update_step() -> None:
        with autocast():
            terms = policy_losses(net, cfg, batch)
        optimizer.zero_grad()
        terms["loss"].backward()
        torch.nn.utils.clip_grad_norm_(net.parameters(), cfg.max_grad_norm)
        optimizer.step()

    obs = torch.rand(1, acting_frames, 8, cfg.view_size, cfg.view_size)
    extra = torch.rand(1, acting_frames, N_EXTRA_INPUTS)
    state = net.initial_state(acting_frames)

    def act_eager() -> None:  # no weight needs a gradient, so ForMICNet.encode keeps the eager layers
        net.requires_grad_(False)
        with autocast():
            net(obs, state, extra)
        net.requires_grad_(True)

    def act_blocked() -> None:  # as the actor acts: no autograd, oneDNN's blocked layout (takes no autocast)
        with torch.no_grad():
            net(obs, state, extra)

    return {"precision": precision, "threads": threads, "update_ms": median_ms(update_step),
            "acting_eager_ms": median_ms(act_eager),
            "acting_blocked_ms": median_ms(act_blocked) if precision == "fp32" else None}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--threads", type=int, nargs="+", default=[1, 2], help="torch thread counts")
    parser.add_argument("--steps", type=int, default=64, help="rollout steps in the update's minibatch")
    parser.add_argument("--agents", type=int, default=64, help="agent sequences in the update's minibatch")
    parser.add_argument("--acting-frames", type=int, default=256, help="frames in one acting forward pass")
    args = parser.parse_args()
    model = next((line.partition(":")[2].strip() for line in open("/proc/cpuinfo") if line.startswith("model name")),
                 "unknown CPU")
    native = sorted(BF16_FLAGS & cpu_flags())
    print(f"{model}; bf16 flags: {', '.join(native) or 'none (bf16 rows skipped)'}")
    print(f"update: forward+backward+Adam, {args.steps} x {args.agents} = {args.steps * args.agents} frames; "
          f"acting: {args.acting_frames} frames; median of 3 rounds of 5 calls")
    print("threads  precision  update ms  acting eager ms  acting blocked ms")
    for threads in args.threads:
        rows = [measure(p, threads, args.steps, args.agents, args.acting_frames)
                for p in PRECISIONS if p == "fp32" or native]
        for row in rows:
            blocked = "-" if row["acting_blocked_ms"] is None else f"{row['acting_blocked_ms']:.1f}"
            print(f"{threads:7d}  {row['precision']:9s}  {row['update_ms']:9.1f}  {row['acting_eager_ms']:15.1f}  "
                  f"{blocked:>17s}")
        if len(rows) == 2:
            fp32, bf16 = rows
            print(f"         bf16 / fp32: update {fp32['update_ms'] / bf16['update_ms']:.2f}x faster, "
                  f"acting (eager) {bf16['acting_eager_ms'] / fp32['acting_eager_ms']:.2f}x the time")


if __name__ == "__main__":
    main()
