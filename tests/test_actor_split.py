"""Actors that split the team act and learn as one actor over all of it (``formic train-ros
--actors K``'s premise): the sampler and the annealing draws are team-wide, and the joined
rollouts are the one rollout ``formic train`` learns from, bit for bit, where the network's
forward pass over a world's rows equals those rows of the team's pass (tested here for the
cpu network and worlds of 4 agents; CPU GEMM kernels may round other batch sizes differently).
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

torch = pytest.importorskip("torch")

from formic_trainer.actor import Actor  # noqa: E402
from formic_trainer.config import make_config  # noqa: E402
from formic_trainer.rollout import Rollout, join_rollouts  # noqa: E402
from formic_trainer.worlds import Frame, MetaAgents  # noqa: E402
from formic_trainer.algorithm import training_network  # noqa: E402

CFG = make_config("cpu", seed=3, teams=(4, 4), world_sizes=((20, 20), (20, 20)), episode_steps=24, rollout_steps=8,
                  filter_anneal_start=0, filter_anneal_end=2)


def rows_of(frame: Frame, rows: np.ndarray) -> Frame:
    return Frame(*(field[rows] for field in frame))


def assert_same_rollout(got: Rollout, want: Rollout) -> None:
    for field in dataclasses.fields(Rollout):
        a, b = getattr(got, field.name), getattr(want, field.name)
        if isinstance(b, np.ndarray):
            assert a.dtype == b.dtype and np.array_equal(a, b), field.name
        elif field.name != "food":  # the parts' food summed in another order
            assert a == b, field.name
    assert got.food == pytest.approx(want.food)


@pytest.mark.parametrize("action_filter", ["mask", "none"])
def test_actors_over_the_worlds_act_as_one_actor_over_the_team(action_filter):
    torch.set_num_threads(1)
    cfg = dataclasses.replace(CFG, action_filter=action_filter)
    net = training_network(cfg)
    envs = MetaAgents(cfg)
    team = Actor(cfg, net, np.arange(8))
    parts = [Actor(cfg, net, np.arange(4)), Actor(cfg, net, np.arange(4, 8))]
    rows = [np.arange(4), np.arange(4, 8)]
    for episode in (1, 3):  # episode 1: the annealed filter leaves some agents unfiltered
        envs.reset(episode)
        for actor in (team, *parts):
            actor.start_episode(episode)
        assert np.concatenate([p.unfiltered for p in parts]).tolist() == team.unfiltered.tolist()
        frame = envs.observe()
        for step in range(cfg.episode_steps):
            actions = team.act(frame)
            split = np.concatenate([p.act(rows_of(frame, r)) for p, r in zip(parts, rows)])
            assert split.tolist() == actions.tolist(), f"episode {episode} step {step}"
            envs.step(actions)
            frame = envs.observe()
            for actor, r in zip((team, *parts), (np.arange(8), *rows)):
                actor.reward(frame.rewards[r])
            if len(team) == cfg.rollout_steps:
                done = step + 1 == cfg.episode_steps
                want = team.rollout(frame, done, 0.0)
                got = join_rollouts([p.rollout(rows_of(frame, r), done, 0.0) for p, r in zip(parts[::-1], rows[::-1])])
                assert_same_rollout(got, want)


def test_an_actor_outside_the_team_is_refused():
    with pytest.raises(ValueError, match="not all in the team of 8"):
        Actor(CFG, training_network(CFG), [6, 7, 8])
