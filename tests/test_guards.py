"""Training guards: the KL bound of a PPO update, the filter's starting probability and the fall
guard (best.pt, rollbacks at a lower learning rate, resumed exactly)."""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import numpy as np
import pytest
import torch

from formic_agent.checkpoint import read_checkpoint
from formic_trainer.actor import filter_probability
from formic_trainer.algorithm import make_optimizer, training_network, update
from formic_trainer.config import load_train_config, make_config
from formic_trainer.guard import BEST, ROLL_BACK, SPENT, WATCH, FallGuard
from formic_trainer.train import Trainer

ROOT = Path(__file__).resolve().parents[1]
TINY = dict(teams=(4,), world_sizes=((16, 16),), episode_steps=32, rollout_steps=16, threads=1)


def actions(guard: FallGuard, foods: list[float], first: int = 1) -> list[str]:
    """The guard's verdicts on episode sets of one episode each, ending at ``first``, ``first + 1``, ..."""
    return [guard.observe(first + i, food).action for i, food in enumerate(foods)]


def test_the_guard_keeps_the_best_full_window_and_rolls_back_below_drop_times_it():
    guard = FallGuard(drop=0.6, window=2, after=0, most=3, lr_factor=0.5)
    # rolling means -, 15, 25, 23, 15 (not below 0.6 x 25 = 15), 8
    assert actions(guard, [10, 20, 30, 16, 14, 2]) == [WATCH, BEST, BEST, WATCH, WATCH, ROLL_BACK]
    assert (guard.best, guard.best_episode, guard.events, guard.lr_factor, guard.window) == (25.0, 3, 1, 0.5, [])


def test_the_fall_line_names_the_rolling_food_the_best_and_the_event():
    guard = FallGuard(drop=0.6, window=1, after=0, most=3, lr_factor=0.5)
    guard.observe(4, 50.0)
    verdict = guard.observe(8, 20.0)
    assert verdict.action == ROLL_BACK
    assert verdict.line == ("guard: rolling food 20.0 < 0.6 x best 50.0 (episode 8): back to episode 4's weights, "
                            "lr x0.5, event 1/3")


def test_the_window_is_cleared_after_a_fall_and_must_fill_again():
    guard = FallGuard(drop=0.5, window=3, after=0, most=3, lr_factor=0.5)
    # rolling means -, -, 10, 7, 4 (< 5: cleared), -, -, 1 (the window full again)
    assert actions(guard, [10, 10, 10, 1, 1, 1, 1, 1]) == [WATCH, WATCH, BEST, WATCH, ROLL_BACK, WATCH, WATCH,
                                                           ROLL_BACK]
    assert (guard.events, guard.lr_factor) == (2, 0.25)


def test_sets_ending_at_or_before_guard_after_are_not_watched():
    guard = FallGuard(drop=0.5, window=2, after=8, most=3, lr_factor=0.5)
    verdicts = [guard.observe(episode, food).action for episode, food in [(4, 100), (8, 100), (12, 5), (16, 5),
                                                                          (20, 1), (24, 1)]]
    assert verdicts == [WATCH, WATCH, WATCH, BEST, WATCH, ROLL_BACK]
    assert (guard.best, guard.best_episode) == (5.0, 16)


def test_after_guard_max_rollbacks_a_fall_is_only_logged():
    guard = FallGuard(drop=0.6, window=1, after=0, most=2, lr_factor=0.5)
    assert actions(guard, [10, 1, 1, 1, 12, 1]) == [BEST, ROLL_BACK, ROLL_BACK, SPENT, BEST, SPENT]
    assert (guard.events, guard.lr_factor, guard.best, guard.best_episode) == (2, 0.25, 12.0, 5)
    spent = guard.observe(7, 2.0)
    assert spent.line == "guard: rolling food 2.0 < 0.6 x best 12.0 (episode 7): no rollback left (2/2 events)"


def test_from_guard_restart_on_the_best_starts_again_and_rollbacks_go_to_the_new_best():
    guard = FallGuard(drop=0.6, window=2, after=0, most=3, lr_factor=0.5, restart=4)
    # sets 1-4: rolling -, 100, 100, 60 (not below 60); set 5 restarts: the window refills (5, 6),
    # its first full mean 20 is the new best (not a fall from 100); 10 then falls below 0.6 x 20
    assert actions(guard, [100, 100, 100, 20, 20, 20, 0]) == [WATCH, BEST, WATCH, WATCH, WATCH, BEST, ROLL_BACK]
    assert (guard.best, guard.best_episode, guard.events, guard.restarted) == (20.0, 6, 1, True)
    restored = FallGuard(drop=0.6, window=2, after=0, most=3, lr_factor=0.5, restart=4)
    restored.load(json.loads(json.dumps(guard.state())))
    assert restored.state() == guard.state()
    legacy = {key: value for key, value in guard.state().items() if key != "restarted"}
    restored.load(legacy)  # a state from before guard_restart existed
    assert restored.restarted is False


def test_a_guard_restored_from_its_state_decides_as_the_original():
    foods = [10, 20, 30, 14, 12, 2, 40, 1, 1]
    whole = FallGuard(drop=0.6, window=2, after=1, most=1, lr_factor=0.5)
    expected = actions(whole, foods)
    first = FallGuard(drop=0.6, window=2, after=1, most=1, lr_factor=0.5)
    head = actions(first, foods[:5])
    second = FallGuard(drop=0.6, window=2, after=1, most=1, lr_factor=0.5)
    second.load(json.loads(json.dumps(first.state())))
    assert head + actions(second, foods[5:], first=6) == expected
    assert second.state() == whole.state()


def test_the_guard_is_off_by_default():
    assert FallGuard.from_config(make_config("cpu")) is None
    assert FallGuard.from_config(make_config("cpu", guard_drop=0.6)).drop == 0.6


@pytest.mark.parametrize("settings", [{"guard_drop": 1.0}, {"guard_drop": -0.1}, {"guard_window": 0},
                                      {"guard_lr_factor": 0.0}, {"filter_initial": 1.5}, {"target_kl": -1.0},
                                      {"guard_restart": -1}])
def test_guard_settings_are_checked(settings):
    with pytest.raises(ValueError):
        make_config("cpu", **settings)


def test_filter_probability_falls_from_filter_initial_to_filter_final():
    cfg = make_config("cpu", filter_anneal_start=10, filter_anneal_end=20, filter_initial=0.5, filter_final=0.0)
    assert [filter_probability(cfg, e) for e in (0, 10, 15, 20, 30)] == [0.5, 0.5, 0.25, 0.0, 0.0]
    # the default starts at 1, as before filter_initial existed
    assert filter_probability(make_config("cpu"), 170) == 1.0 + (130 / 260) * (0.0 - 1.0)
    # the crowd stage of paper-v2: no filter from its first episode
    crowd = make_config("cpu", filter_anneal_start=0, filter_anneal_end=1, filter_initial=0.0)
    assert filter_probability(crowd, 0) == 0.0
    assert filter_probability(dataclasses.replace(crowd, filter_initial=1.0), 0) == 1.0  # paper.toml's crowd


def one_update(cfg) -> tuple[dict, dict]:
    """The stats and weights of one update of fresh weights on the first rollout of a tiny run."""
    from formic_trainer.actor import Actor
    from formic_trainer.train import play_episode_set
    from formic_trainer.worlds import MetaAgents

    torch.manual_seed(0)
    net = training_network(cfg)
    envs = MetaAgents(cfg)
    rollouts = []
    play_episode_set(cfg, envs, Actor(cfg, net, np.arange(envs.n_agents)), 0, lambda r, _: rollouts.append(r))
    optimizer = make_optimizer(net, cfg)
    stats = update(net, optimizer, cfg, rollouts[0], np.random.default_rng(0))
    return stats, {k: v.clone() for k, v in net.state_dict().items()}


def test_an_update_stops_at_the_first_minibatch_over_one_and_a_half_target_kl():
    base = make_config("cpu", **TINY, lr=1e-2)
    off, off_weights = one_update(base)
    assert off["update_fraction"] == 1.0 and off["approx_kl"] > 0
    loose, loose_weights = one_update(dataclasses.replace(base, target_kl=1e6))
    assert loose == off and all(torch.equal(loose_weights[k], v) for k, v in off_weights.items())
    # the first minibatch sees the acting weights (KL ~0), each later one weights moved by lr 1e-2
    tight, tight_weights = one_update(dataclasses.replace(base, target_kl=1e-6))
    assert tight["update_fraction"] == 1 / 12  # 3 epochs x 4 minibatches planned, one step taken
    assert not all(torch.equal(tight_weights[k], v) for k, v in off_weights.items())


def test_config_files_from_before_the_guards_load_with_them_off():
    cfg = load_train_config(ROOT / "models" / "training" / "paper-novalid" / "config.json")
    assert (cfg.target_kl, cfg.filter_initial, cfg.guard_drop) == (None, 1.0, None)


GUARDED = dict(TINY, guard_drop=0.99, guard_window=1, guard_max=3, lr=1e-3)


def test_a_guarded_run_rolls_back_to_best_pt_at_a_lower_lr_and_resumes_bit_for_bit(tmp_path):
    lines: list[str] = []
    cfg = make_config("cpu", **GUARDED)
    whole = Trainer(cfg, tmp_path / "whole", resume=False, log=lines.append)
    whole.train(episodes=4)
    falls = [line for line in lines if line.startswith("guard: ")]
    guard = whole.learner.guard
    best = read_checkpoint(tmp_path / "whole" / "best.pt")
    assert best["progress"]["episode"] == guard.best_episode
    assert "optimizer" not in best  # a rollback starts a fresh optimiser: best.pt keeps weights and counters
    assert best["progress"]["guard"]["best"] == guard.best
    assert guard.lr_factor == 0.5 ** guard.events
    assert whole.learner.optimizer.param_groups[0]["lr"] == pytest.approx(1e-3 * guard.lr_factor)
    # 2 + resume + 2 episode sets: the same rollbacks, the same weights
    Trainer(cfg, tmp_path / "parts", resume=False, log=lambda *_: None).train(episodes=2)
    resumed_lines: list[str] = []
    resumed = Trainer(cfg, tmp_path / "parts", resume=True, log=resumed_lines.append)
    resumed.train(episodes=2)
    later = [line for line in resumed_lines if line.startswith("guard: ")]
    assert later == [line for line in falls if "(episode 3)" in line or "(episode 4)" in line]
    # the tiny config falls in both halves: the resumed half rolls back with the restored count
    assert "event 1/3" in falls[0] and "event 2/3" in later[0]
    assert resumed.learner.guard.state() == guard.state()
    for key, value in whole.net.state_dict().items():
        assert torch.equal(value, resumed.net.state_dict()[key]), key
