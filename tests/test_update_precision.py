"""``update_precision``: the PPO update's forward+backward under bf16 autocast, opt-in, refused
on a CPU without native bf16; acting stays fp32."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
import torch

from formic_trainer.actor import Actor
from formic_trainer.algorithm import BF16_FLAGS, check_update_precision, cpu_flags, make_optimizer, \
    training_network, update
from formic_trainer.config import make_config
from formic_trainer.train import play_episode_set
from formic_trainer.worlds import MetaAgents
from formic_world.errors import InputError

TINY = make_config("cpu", network="cpu-feedback", teams=(4,), world_sizes=((16, 16),), episode_steps=32,
                   rollout_steps=16, threads=1, lr=1e-3)
NATIVE = bool(BF16_FLAGS & cpu_flags())


def one_update(cfg) -> tuple[np.ndarray, torch.Tensor, torch.Tensor]:
    """The first rollout's behaviour log-probabilities, and the weights before and after one
    update (3 epochs x 4 minibatches) on it, from fresh weights."""
    torch.manual_seed(0)
    net = training_network(cfg)
    before = torch.cat([p.detach().flatten().clone() for p in net.parameters()])
    envs = MetaAgents(cfg)
    rollouts = []
    play_episode_set(cfg, envs, Actor(cfg, net, np.arange(envs.n_agents)), 0, lambda r, _: rollouts.append(r))
    update(net, make_optimizer(net, cfg), cfg, rollouts[0], np.random.default_rng(0))
    assert all(p.dtype == torch.float32 for p in net.parameters())  # autocast computes in bf16, keeps fp32 weights
    return rollouts[0].logprobs, before, torch.cat([p.detach().flatten() for p in net.parameters()])


@pytest.mark.skipif(not NATIVE, reason="this CPU has no amx_bf16 or avx512_bf16")
def test_a_bf16_update_moves_the_weights_as_fp32_does_within_a_tenth_and_acts_the_same():
    """Tolerance: the bf16 update's change to the weights differs from fp32's by under 10% of
    fp32's change (L2 norm over all weights; measured 4%), and it is not fp32's change."""
    fp32_logprobs, start, fp32 = one_update(TINY)
    bf16_logprobs, bf16_start, bf16 = one_update(dataclasses.replace(TINY, update_precision="bf16"))
    assert np.array_equal(fp32_logprobs, bf16_logprobs)  # acting is fp32 in both
    assert torch.equal(start, bf16_start)
    moved = fp32 - start
    assert torch.linalg.norm(bf16 - fp32) < 0.1 * torch.linalg.norm(moved)
    assert not torch.equal(bf16, fp32)


def test_bf16_is_refused_in_one_line_on_a_cpu_without_its_flags_and_fp32_is_the_default():
    assert TINY.update_precision == make_config("paper").update_precision == "fp32"
    bf16 = dataclasses.replace(TINY, update_precision="bf16")
    without = frozenset({"fpu", "avx2", "avx512f", "avx512_vnni"})
    with pytest.raises(InputError) as refused:
        check_update_precision(bf16, flags=lambda: without)
    assert str(refused.value) == ("update_precision 'bf16' needs a CPU with amx_bf16 or avx512_bf16 (not in this "
                                  "CPU's /proc/cpuinfo flags): use 'fp32'")
    for flag in ("amx_bf16", "avx512_bf16"):
        check_update_precision(bf16, flags=lambda: without | {flag})
    check_update_precision(TINY, flags=frozenset)  # fp32 needs no flag
    with pytest.raises(ValueError, match="update_precision must be one of 'fp32', 'bf16', not 'fp16'"):
        dataclasses.replace(TINY, update_precision="fp16")


def test_the_cpu_flags_are_the_first_flags_line_of_cpuinfo(tmp_path):
    cpuinfo = tmp_path / "cpuinfo"
    cpuinfo.write_text("processor\t: 0\nmodel name\t: Some CPU\nflags\t\t: fpu avx512_bf16 amx_tile\n\n"
                       "processor\t: 1\nflags\t\t: fpu\n")
    assert cpu_flags(cpuinfo) == {"fpu", "avx512_bf16", "amx_tile"}
    assert cpu_flags(tmp_path / "missing") == frozenset()
