"""Policy throughput: batched inference, and whole training iterations end to end."""

from __future__ import annotations

import tempfile
import time

import torch

from formic_agent.inputs import NETWORK_PRESETS, N_EXTRA_INPUTS

from formic_agent.network import ForMICNet, count_parameters

from .config import make_config
from .train import Trainer


def bench_policy(network: str, batch: int, threads: int, episodes: int = 1) -> dict:
    torch.set_num_threads(threads)
    net = ForMICNet(NETWORK_PRESETS[network]).eval()
    obs = torch.rand(1, batch, 8, 11, 11)
    extra = torch.zeros(1, batch, N_EXTRA_INPUTS)
    state = net.initial_state(batch)
    with torch.no_grad():
        for _ in range(5):
            net(obs, state, extra)
        start = time.perf_counter()
        calls = 0
        while time.perf_counter() - start < 2.0:
            _, _, state = net(obs, state, extra)
            calls += 1
    inference = calls * batch / (time.perf_counter() - start)
    cfg = make_config("cpu", network=network, threads=threads, curriculum=True)
    with tempfile.TemporaryDirectory() as run_dir:
        trainer = Trainer(cfg, run_dir, resume=False, log=lambda *_: None)
        start = time.perf_counter()
        for _ in range(episodes):
            trainer.run_episode_set()
        seconds = time.perf_counter() - start
        steps = trainer.env_steps
    return {
        "network": network,
        "parameters": count_parameters(net),
        "threads": threads,
        "inference_batch": batch,
        "inference_agent_steps_per_s": inference,
        "training_agent_steps_per_s": steps / seconds,
        "training_seconds": seconds,
        "training_agent_steps": steps,
        "network_config": net.config.to_dict(),
    }
