"""analysis/join_pressure.py: each loss term's first-order effect on P(JOIN) is what a small step
down that term's gradient really does."""

from __future__ import annotations

import pytest
import torch

from formic_agent.checkpoint import load_network
from formic_cli.options import training_config
from analysis.join_pressure import CONTROL, SOURCES, effects, join_probability_gradient, rollout_batches, term_gradients

SMALL = ("teams=8", "world_sizes=20-20", "episode_steps=96", "rollout_steps=48")


@pytest.fixture(autouse=True)
def one_torch_thread():
    """As the script runs (small batches: a second thread only contends, 80x slower on a busy machine)."""
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(threads)


@pytest.fixture
def small_rollout():
    """The shipped model's rollout of one episode in a small world, under the control recipe."""
    torch.manual_seed(0)
    cfg = training_config("cpu", None, CONTROL + SMALL)
    net, _ = load_network("models/formic_paper.pt")
    return cfg, net, rollout_batches(cfg, net, episodes=1)


def test_each_terms_effect_is_the_change_a_small_step_makes(small_rollout):
    cfg, net, batches = small_rollout
    p_join, states, direction = join_probability_gradient(net, batches)
    assert states > 0 and 0.0 < p_join < 1.0
    grads = term_gradients(cfg, net, batches)
    predicted = effects(grads, direction)
    assert predicted["all"] == pytest.approx(sum(predicted[t] for t in ("policy", "entropy", "valid", "value")))
    params = list(net.parameters())
    original = [p.detach().clone() for p in params]

    def probability_after(step: float, term: str) -> float:
        with torch.no_grad():
            for p, o, g in zip(params, original, grads[term]):
                p.copy_(o - step * g)
        moved, _, _ = join_probability_gradient(net, batches)
        with torch.no_grad():
            for p, o in zip(params, original):
                p.copy_(o)
        return moved

    for term in ("valid", "policy"):
        step = 1e-4 / sum(float((g * g).sum()) for g in grads[term]) ** 0.5  # a parameter change of length 1e-4
        change = (probability_after(step, term) - probability_after(-step, term)) / 2  # central: second order cancels
        assert change == pytest.approx(step * predicted[term], rel=0.02)


def test_the_effects_split_by_source_add_up_to_the_whole(small_rollout):
    cfg, net, batches = small_rollout
    _, _, direction = join_probability_gradient(net, batches)
    whole = effects(term_gradients(cfg, net, batches), direction)
    parts = [effects(term_gradients(cfg, net, batches, source), direction) for source in SOURCES.values()]
    for term in whole:
        assert sum(part[term] for part in parts) == pytest.approx(whole[term], rel=1e-4, abs=1e-9)
    assert all(part["policy"] != 0.0 for part in parts), "every source contributes to the policy gradient"
