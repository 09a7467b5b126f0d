"""The schedule clock (anneal_hold): the filter's and highways' schedules pause while food falls,
go back with a rollback, resume exactly, and equal the episode count when the hold is off."""

from __future__ import annotations

import json

import pytest
from click.testing import CliRunner

from formic_agent.checkpoint import read_checkpoint
from formic_trainer.actor import filter_probability
from formic_trainer.config import make_config, require_distributable
from formic_trainer.guard import BEST, WATCH, FallGuard
from formic_trainer.learner import Learner
from formic_trainer.schedule import ScheduleClock
from formic_trainer.train import Trainer
from formic_world.pheromones import curriculum_intensities

TINY = dict(teams=(4,), world_sizes=((16, 16),), episode_steps=32, rollout_steps=16, threads=1)


def clock_after(clock: ScheduleClock, foods: list[float], episodes: int = 4) -> list[tuple[int, bool]]:
    """(clock, held) after each episode set of ``episodes`` episodes with these foods."""
    out = []
    for food in foods:
        clock.observe(episodes, food)
        out.append((clock.episode, clock.held))
    return out


def test_without_a_hold_the_clock_is_the_episode_count():
    clock = ScheduleClock(hold=None, window=2, memory=3)
    assert clock_after(clock, [100, 0, 0, 0]) == [(4, False), (8, False), (12, False), (16, False)]
    assert (clock.window, clock.peaks) == ([], [])


def test_the_clock_holds_while_the_rolling_food_is_under_hold_times_its_recent_peak():
    clock = ScheduleClock(hold=0.8, window=2, memory=3)
    # rolling means -, 100, 100, 80 (not under 0.8 x 100), 60 (held), 60 (held), 90 (not held)
    assert clock_after(clock, [100, 100, 100, 60, 60, 60, 120]) == [
        (4, False), (8, False), (12, False), (16, False), (16, True), (16, True), (20, False)]


def test_a_lower_level_that_lasts_becomes_the_reference_when_the_peak_ages_out():
    clock = ScheduleClock(hold=0.8, window=1, memory=3)
    # peaks over the last 3 rolling means: 100 is forgotten at the fourth set after it
    assert clock_after(clock, [100, 50, 50, 50, 50]) == [
        (4, False), (4, True), (4, True), (8, False), (12, False)]


def test_a_clock_restored_from_its_state_decides_as_the_original():
    foods = [100, 90, 40, 40, 95, 30, 30, 30, 80]
    whole = ScheduleClock(hold=0.7, window=2, memory=4)
    expected = clock_after(whole, foods)
    first = ScheduleClock(hold=0.7, window=2, memory=4)
    head = clock_after(first, foods[:4])
    second = ScheduleClock(hold=0.7, window=2, memory=4)
    second.load(json.loads(json.dumps(first.state())))
    assert head + clock_after(second, foods[4:]) == expected
    assert second.state() == whole.state()


def test_the_guard_reads_after_and_restart_on_the_schedule_clock():
    guard = FallGuard(drop=0.5, window=1, after=8, most=3, lr_factor=0.5, restart=12)
    # episodes run on while the clock stays at 8: not watched yet
    assert guard.observe(12, 100.0, schedule=8).action == WATCH
    assert guard.observe(16, 100.0, schedule=12).action == BEST
    assert not guard.restarted
    assert guard.observe(20, 10.0, schedule=16).action == BEST  # played from 12 on: the record restarts
    assert (guard.restarted, guard.best, guard.best_episode) == (True, 10.0, 20)


@pytest.mark.parametrize("settings", [{"anneal_hold": 1.0}, {"anneal_hold": -0.1}, {"anneal_memory": 0}])
def test_schedule_settings_are_checked(settings):
    with pytest.raises(ValueError):
        make_config("cpu", **settings)


def end_sets(learner: Learner, foods: list[float]) -> list[int]:
    """The clock after each of these one-episode sets."""
    out = []
    for food in foods:
        learner.end_episodes(1, {"food_mean": food})
        out.append(learner.schedule.episode)
    return out


def test_a_rollback_sets_the_clock_back_to_best_pt_and_a_resume_keeps_it(tmp_path):
    cfg = make_config("cpu", **TINY, anneal_hold=0.9, anneal_memory=10, guard_drop=0.5, guard_window=1)
    learner = Learner(cfg, tmp_path, resume=False, log=lambda *_: None)
    # 100: best at clock 1; 85: held (clock 1); 95 advances; 40 < 0.5 x 100: rollback to best.pt's clock 1
    assert end_sets(learner, [100, 85, 95]) == [1, 1, 2]
    assert read_checkpoint(tmp_path / "best.pt")["progress"]["schedule"]["episode"] == 1
    end_sets(learner, [40])
    assert (learner.episode, learner.schedule.episode, learner.guard.events) == (4, 1, 1)
    learner.close()
    resumed = Learner(cfg, tmp_path, resume=True, log=lambda *_: None)
    assert resumed.schedule.state() == learner.schedule.state()


def test_without_a_hold_a_rollback_leaves_the_clock_at_the_episode_count(tmp_path):
    cfg = make_config("cpu", **TINY, guard_drop=0.5, guard_window=1)
    learner = Learner(cfg, tmp_path, resume=False, log=lambda *_: None)
    assert end_sets(learner, [100, 95, 40]) == [1, 2, 3]  # the third set rolls back to episode 1's weights
    assert (learner.guard.events, learner.episode, learner.schedule.episode) == (1, 3, 3)


def test_a_checkpoint_from_before_the_clock_resumes_with_the_clock_at_its_episode(tmp_path):
    cfg = make_config("cpu", **TINY)
    learner = Learner(cfg, tmp_path, resume=False, log=lambda *_: None)
    end_sets(learner, [1.0, 2.0, 3.0])
    payload = read_checkpoint(tmp_path / "latest.pt")
    del payload["progress"]["schedule"]
    import torch

    torch.save(payload, tmp_path / "latest.pt")
    assert Learner(cfg, tmp_path, resume=True, log=lambda *_: None).schedule.episode == 3


def test_the_filter_and_the_highways_read_the_clock_and_the_scenarios_the_episode(tmp_path):
    cfg = make_config("cpu", **TINY, anneal_hold=0.5, filter_anneal_start=0, filter_anneal_end=300,
                      curriculum_start=0, curriculum_end=300)
    trainer = Trainer(cfg, tmp_path / "held", resume=False, log=lambda *_: None)
    trainer.learner.schedule.episode = 150  # as if the clock had held for 150 episodes
    stats = trainer.run_episode_set()
    assert stats["schedule_episode"] == 150 and stats["filter_probability"] == filter_probability(cfg, 150) == 0.5
    highway, deposit = curriculum_intensities(150, 0, 300)
    assert (stats["highway_intensity"], stats["deposit_strength"]) == (highway, deposit)
    plain = Trainer(cfg, tmp_path / "plain", resume=False, log=lambda *_: None)
    plain_stats = plain.run_episode_set()
    assert plain_stats["filter_probability"] == 1.0  # episode 0's
    # the scenarios are episode 0's in both (the clock moves the schedules, not the draws)
    assert [w.scenario.seed for w in trainer.envs.worlds] == [w.scenario.seed for w in plain.envs.worlds]


def test_without_a_hold_a_run_logs_no_clock_and_its_clock_is_its_episode(tmp_path):
    lines: list[str] = []
    trainer = Trainer(make_config("cpu", **TINY), tmp_path, resume=False, log=lines.append)
    trainer.train(episodes=2)
    assert trainer.learner.schedule.episode == trainer.episode == 2
    assert lines and not any(" sched " in line for line in lines)


def test_a_run_ends_when_its_clock_reaches_schedule_end_and_a_resumed_run_finds_it_ended(tmp_path):
    cfg = make_config("cpu", **TINY, anneal_hold=0.5, schedule_end=5, total_episodes=20)
    trainer = Trainer(cfg, tmp_path, resume=False, log=lambda *_: None)
    trainer.learner.schedule.episode = 3  # as if the clock had held for 3 episodes
    trainer.train()
    assert (trainer.episode, trainer.learner.schedule.episode, trainer.ended) == (2, 5, True)
    resumed = Trainer(cfg, tmp_path, log=lambda *_: None)
    assert resumed.ended
    resumed.train()
    assert resumed.episode == 2  # nothing more played
    # total_episodes still caps a clock that never gets there; without schedule_end the episodes decide
    capped = Trainer(make_config("cpu", **TINY, anneal_hold=0.5, schedule_end=50, total_episodes=2),
                     tmp_path / "capped", resume=False, log=lambda *_: None)
    capped.train()
    assert (capped.episode, capped.ended) == (2, True)
    assert not Trainer(make_config("cpu", **TINY, total_episodes=3), tmp_path / "plain", resume=False,
                       log=lambda *_: None).ended


def test_schedule_end_is_resumable_and_zero_is_off(tmp_path):
    assert make_config("cpu", schedule_end=0).schedule_end is None
    with pytest.raises(ValueError, match="schedule_end must be > 0"):
        make_config("cpu", schedule_end=-5)
    Trainer(make_config("cpu", **TINY, schedule_end=1), tmp_path, resume=False, log=lambda *_: None).train()
    # the same run resumes with another end (it says where to stop, not what is trained)
    assert Trainer(make_config("cpu", **TINY, schedule_end=3), tmp_path, log=lambda *_: None).episode == 1


def test_distributed_training_refuses_the_hold_with_one_line():
    with pytest.raises(ValueError, match="anneal_hold=0"):
        require_distributable(make_config("cpu", anneal_hold=0.8))
    require_distributable(make_config("cpu"))
    from formic_cli.main import cli

    result = CliRunner().invoke(cli, ["train-ros", "--episodes", "1", "--set", "anneal_hold=0.8", "--set", "teams=4"])
    assert result.exit_code != 0
    assert "anneal_hold" in result.output and "formic train" in result.output
