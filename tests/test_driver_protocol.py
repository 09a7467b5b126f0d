"""The driver protocol both agent hosts follow (exact turns, no ROS), and the learning host's
food: the in-process trainer's, by the world's definition, also where counting load drops
was not."""

from __future__ import annotations

import functools

import numpy as np
import pytest

from formic_ros.drivers.protocol import DriverProtocol, Turn

IGNORE, HOLD, RESEND, START, STEP, END = Turn.IGNORE, Turn.HOLD, Turn.RESEND, Turn.START, Turn.STEP, Turn.END


def play(protocol: DriverProtocol, *observations) -> list[Turn]:
    """The turns for (step, done) observations, each answered at once when it is to answer."""
    turns = []
    for step, done in observations:
        turns.append(protocol.receive(step, done))
        if turns[-1] in (START, STEP):
            protocol.answered(step)
    return turns


def test_a_learning_host_plays_whole_episodes_of_new_scenarios():
    protocol = DriverProtocol(whole_episodes=True)
    assert play(protocol, (0, False)) == [HOLD]  # step 0 before its scenario
    assert protocol.scenario("A") is False  # the episode starts at step 0, not now
    assert play(protocol, (0, False), (0, False), (1, False), (3, False), (1, False), (2, False), (0, False),
                (3, True), (3, True), (0, False)) == [
        START, RESEND, STEP, IGNORE, RESEND, STEP, IGNORE, END, IGNORE, HOLD]
    assert protocol.ended and not protocol.playing and protocol.taken == 3
    assert protocol.scenario("A") is False and play(protocol, (0, False)) == [HOLD]  # a played scenario
    protocol.scenario("B")
    assert play(protocol, (2, False), (0, True), (0, False), (1, False)) == [IGNORE, IGNORE, START, STEP]
    assert not protocol.cut_short


def test_a_learning_host_ignores_a_resend_of_the_step_it_has_not_answered():
    protocol = DriverProtocol(whole_episodes=True)
    protocol.scenario("A")
    assert protocol.receive(0, False) is START  # waits for weights: not answered yet
    assert [protocol.receive(0, False), protocol.receive(1, False)] == [IGNORE, IGNORE]
    protocol.answered(0)
    assert [protocol.receive(0, False), protocol.receive(1, False)] == [RESEND, STEP]
    assert protocol.receive(1, False) is IGNORE and protocol.answered_step == 0


def test_a_new_scenarios_step_0_cuts_a_learning_hosts_episode_short():
    protocol = DriverProtocol(whole_episodes=True)
    protocol.scenario("A")
    assert play(protocol, (0, False), (1, False)) == [START, STEP]
    protocol.scenario("B")  # the world moved on; the final observation of A was lost
    assert play(protocol, (2, False), (0, False), (1, False)) == [STEP, START, STEP]
    assert protocol.cut_short and protocol.played == "B" and protocol.answered_step == 1


def test_a_plain_host_joins_anywhere_and_plays_a_scenario_again():
    protocol = DriverProtocol(whole_episodes=False)
    assert play(protocol, (0, False)) == [IGNORE]  # no scenario: the world re-sends
    assert protocol.scenario("A") is True  # starts at once: a restarted host joins mid-episode
    assert protocol.scenario("A") is False
    assert play(protocol, (5, False), (5, False), (4, False), (7, False), (7, True), (8, False), (0, False),
                (1, False)) == [STEP, RESEND, IGNORE, STEP, END, IGNORE, START, STEP]
    assert not protocol.ended and protocol.answered_step == 1
    assert play(protocol, (2, True)) == [END] and protocol.ended
    assert protocol.scenario("B") is True and not protocol.ended and protocol.answered_step == -1


def test_the_learning_hosts_food_is_the_in_process_trainers(monkeypatch):
    """Same seed and config, chunk by chunk: the learning host's rollouts carry the food of
    ``formic train``'s, to the bit, with a dropoff rate of 0.3 (loads in tenths on the float32
    wire), where summing the messages' load drops gave other numbers."""
    torch = pytest.importorskip("torch")
    pytest.importorskip("formic_interfaces.msg")
    from formic_ros import convert
    from formic_ros.drivers.host_actor import HostActor
    from formic_ros.wire import read
    from formic_trainer import worlds
    from formic_trainer.actor import Actor
    from formic_trainer.config import make_config
    from formic_trainer.train import play_episode_set
    from formic_world import World
    from formic_world.geometry import N_ACTIONS

    monkeypatch.setattr(worlds, "WorldConfig", functools.partial(worlds.WorldConfig, dropoff_rate=0.3))
    torch.manual_seed(0)
    cfg = make_config("cpu", seed=5, teams=(8,), world_sizes=((20, 20),), episode_steps=96, rollout_steps=7,
                      learning_agents=-1, curriculum=False)
    host = HostActor(cfg, range(8))
    in_process = []
    envs = worlds.MetaAgents(cfg)
    play_episode_set(cfg, envs, Actor(cfg, host.net, host.ids), 0, lambda rollout, _: in_process.append(rollout))
    actions = np.concatenate([r.actions for r in in_process])  # every agent learns: all its actions

    (scenario,), _, _ = worlds.sample_scenarios(cfg, worlds.scenario_rng(cfg, 0), 0)
    assert scenario.config.dropoff_rate == 0.3
    world, rewards, ids = World(scenario), np.zeros(8), host.ids
    foods, drops, last_loads = [], [], None
    for step in range(cfg.episode_steps + 1):  # what the world node sends, read as the learning host reads it
        valid = world.action_mask()
        msg = convert.encode_observation_batch(worlds.AgentBatch.from_world(world, action_mask=valid), rewards,
                                               world.done, train_masks=world.training_action_mask(valid))
        rows = convert.rows_of(msg, ids)
        batch = convert.decode_observation_batch(msg, rows)
        if step == 0:
            host.begin(batch, scenario.config.load_denominator)
            drop = 0.0
        frame = host.frame(batch, read(msg.train_masks, np.uint8).reshape(-1, N_ACTIONS)[rows].astype(bool),
                           read(msg.rewards, np.float32), rows)
        if step:
            drop += float(np.clip(last_loads - batch.loads, 0.0, None).sum())  # the former count
            rollout = host.outcome(frame, batch.loads, world.done)
            if rollout is not None:
                foods.append(rollout.food)
                drops.append(drop)
                drop = 0.0
        last_loads = batch.loads
        if not world.done:
            host.act_on(batch, frame)
            rewards = world.step(actions[step]).rewards
    want = [r.food for r in in_process]
    assert len(foods) == len(want) == 14 and sum(want) > 3
    assert foods == want
    assert drops != want  # the load drops' count differs here
