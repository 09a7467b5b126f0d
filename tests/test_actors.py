"""`formic train-ros --actors 2` reproduces `formic train` on two worlds.

Two tiny worlds (4 agents each, 20x20, 32-step episodes, 16-step rollouts, the cpu preset):
`formic train` in this process for two episode sets, and the trainer node with two actors
(each a world and its learning host: five real processes, own domain) for the same four
environment episodes. The same scenarios, the same food in every world and episode, and the
same final weights, bit for bit (the actors' team-wide draws, the trainer's joined rollouts:
tests/test_actor_split.py)."""

from __future__ import annotations

import json
import os
import re
import signal
import time

import pytest

pytest.importorskip("rclpy")
pytest.importorskip("formic_interfaces.msg")
torch = pytest.importorskip("torch")

from ros_helpers import Spawner, fresh_domain_id  # noqa: E402

from formic_agent.checkpoint import read_checkpoint  # noqa: E402
from formic_ros.drivers.lag import AHEAD_CHUNKS  # noqa: E402
from formic_trainer.config import make_config  # noqa: E402
from formic_trainer.train import Trainer  # noqa: E402

pytestmark = pytest.mark.filterwarnings("ignore::UserWarning", "ignore:module 'sre_:DeprecationWarning")

CFG = make_config("cpu", seed=3, teams=(4, 4), world_sizes=((20, 20), (20, 20)), episode_steps=32, rollout_steps=16,
                  team_reward=0.25)


def test_two_actors_match_the_in_process_trainer(tmp_path):
    torch.set_num_threads(1)
    trainer = Trainer(CFG, tmp_path / "in_process", resume=False, log=lambda _: None)
    want = []  # (episode, world, seed, food)
    for _ in range(2):
        episode = trainer.episode
        stats = trainer.run_episode_set()
        want += [(episode, k, w.scenario.seed, stats[f"food_env{k}"]) for k, w in enumerate(trainer.envs.worlds)]
    trainer.close()
    assert sum(food for *_, food in want) > 0, "the setting must collect food to compare"

    config_file = tmp_path / "train_config.json"
    config_file.write_text(json.dumps(CFG.to_dict()))
    spawner = Spawner(tmp_path, fresh_domain_id())
    try:
        run = spawner.formic("train_ros_actors", "train-ros", "--train-config", str(config_file), "--actors", "2",
                             "--run-dir", str(tmp_path / "actors"), "--episodes", "4", "--domain-id",
                             str(spawner.domain_id), "--timeout", "100", "--json", "--fresh", limit_s=130)
        assert run.wait() == 0, run.output()[-3000:]
        result = run.json_line()
    finally:
        spawner.reap_all()
    got = [(e["episode"], e["actor"], e["seed"], e["food"]) for e in result["episodes"]]
    assert got == sorted(want)
    assert all(e["missed_actions"] == 0 for e in result["episodes"])
    assert result["trainer"]["version"] == 4 and result["trainer"]["dropped"] == 0 and result["trainer"]["lost"] == 0
    assert set(result["exit_codes"].values()) == {0}
    saved = read_checkpoint(tmp_path / "actors" / "latest.pt")
    assert saved["progress"]["episode"] == 4 and saved["progress"]["updates"] == 4
    weights = trainer.net.state_dict()
    assert saved["state_dict"].keys() == weights.keys()
    for key in weights:
        assert torch.equal(saved["state_dict"][key], weights[key]), key


def test_a_killed_actor_is_left_out_and_a_restarted_one_rejoins(tmp_path):
    """`formic trainer --actors 2` with two `formic actor` processes: actor 1 is SIGKILLed
    (world and host with it) mid-episode; within the 3 s deadline the trainer updates from
    actor 0 alone, one warning line naming actor 1 per lost rollout, counted; actor 1
    restarted takes the newest weights and its rollouts join the updates again (8x8)."""
    config_file = tmp_path / "train_config.json"
    config_file.write_text(json.dumps({**CFG.to_dict(), "rollout_steps": 8}))
    spawner = Spawner(tmp_path, fresh_domain_id())
    domain = ["--domain-id", str(spawner.domain_id), "--train-config", str(config_file)]
    try:
        trainer = spawner.formic("trainer", "trainer", *domain, "--run-dir", str(tmp_path / "run"), "--fresh",
                                 "--actors", "2", "--actor-deadline", "3", "--max-updates", "24", "--json",
                                 limit_s=150)
        spawner.formic("actor0", "actor", *domain, "--actor", "0", "--episodes", "6", limit_s=150)
        actor1 = spawner.formic("actor1", "actor", *domain, "--actor", "1", "--episodes", "6", limit_s=150)
        trainer.wait_for_text("update 2: 8x8", timeout=90)  # both actors joined, mid-episode
        actor1.kill()
        trainer.wait_for_text("actor 1 sent no rollout", timeout=30)
        spawner.formic("actor1_again", "actor", *domain, "--actor", "1", "--episodes", "6",
                                   "--first-episode", "2", limit_s=150)
        assert trainer.wait() == 0, trainer.output()[-3000:]
        result = trainer.json_line()
        log = trainer.output()
    finally:
        spawner.reap_all()
    lost_lines = [line for line in log.splitlines() if "sent no rollout" in line]
    assert result["updates"] == 24 and result["lost"] == len(lost_lines) >= 1
    assert all("actor 1 sent no rollout of weights version" in line and "from actor 0 (" in line
               for line in lost_lines)
    assert "8x8" in log[log.rindex("sent no rollout"):], "the restarted actor never joined an update again"


def kill_trainer_at_update_3(tmp_path, spawner, trainer_flags: tuple[str, ...] = (), actor_flags: tuple[str, ...] = ()):
    """`formic trainer --actors 2` (with ``trainer_flags``) and two `formic actor`s of 4 episodes
    (with ``actor_flags``); the trainer SIGKILLed once it logs update 3. Returns the trainer's
    arguments (to start it again), the actors and the killed trainer's checkpoint progress."""
    config_file = tmp_path / "train_config.json"
    config_file.write_text(json.dumps(CFG.to_dict()))
    domain = ["--domain-id", str(spawner.domain_id), "--train-config", str(config_file)]
    trainer_args = ("trainer", *domain, "--run-dir", str(tmp_path / "run"), "--actors", "2", *trainer_flags, "--json")
    first = spawner.formic("trainer", *trainer_args, "--fresh", limit_s=60)
    actors = [spawner.formic(f"actor{k}", "actor", *domain, "--actor", str(k), "--episodes", "4", *actor_flags,
                             "--json", limit_s=90) for k in range(2)]
    first.wait_for_text("update 3:", timeout=45)
    first.kill()
    return trainer_args, actors, read_checkpoint(tmp_path / "run" / "latest.pt")["progress"]


def test_a_trainer_killed_and_restarted_from_its_checkpoint_goes_on_with_the_actors(tmp_path):
    """`formic trainer --actors 2` SIGKILLed after its first checkpoint (episode set 1: updates
    1-2) and its third update, under two running `formic actor`s (4 episodes each, 2 rollouts an
    episode), and started again on the same run dir. The actors wait for it (their worlds'
    deadline is long) and go on with its weights: it resumes at the checkpoint's version 2, and
    what a SIGKILL loses is what came after the checkpoint: update 3 and episode set 2, whose
    last rollouts (of version 3) went to the killed trainer. The restarted one learns sets 3 and
    4 (updates 3-6); its checkpoint holds 6 updates and 6 episodes."""
    run_dir = tmp_path / "run"
    spawner = Spawner(tmp_path, fresh_domain_id())
    try:
        trainer_args, actors, checkpoint = kill_trainer_at_update_3(tmp_path, spawner)
        for actor in actors:  # set 2 ended: its last rollouts went to the killed trainer
            deadline = time.monotonic() + 20
            while actor.output().count("episode over") < 2:
                assert time.monotonic() < deadline, actor.output()[-3000:]
                time.sleep(0.05)
        again = spawner.formic("trainer_again", *trainer_args, "--max-updates", "4", limit_s=60)
        assert [actor.wait() for actor in actors] == [0, 0], actors[0].output()[-3000:] + actors[1].output()[-3000:]
        assert again.wait() == 0, again.output()[-3000:]
        result, log = again.json_line(), again.output()
        played = [actor.json_line()["episodes"] for actor in actors]
        host_logs = [actor.output() for actor in actors]
    finally:
        spawner.reap_all()
    assert (checkpoint["updates"], checkpoint["episode"]) == (2, 2)
    assert "resumed from" in log and "weights version 2 published" in log
    assert re.findall(r"\]: update (\d+):", log) == ["3", "4", "5", "6"]
    assert (result["version"], result["updates"], result["dropped"], result["lost"]) == (6, 4, 0, 0)
    assert [[e["episode"] for e in episodes] for episodes in played] == [[0, 2, 4, 6]] * 2  # by episode set
    assert all(e["missed_actions"] == 0 for episodes in played for e in episodes)
    assert all(host_log.count("weights version 2 after version 3: the trainer restarted") == 1
               for host_log in host_logs)
    saved = read_checkpoint(run_dir / "latest.pt")["progress"]
    assert (saved["updates"], saved["episode"]) == (6, 6)


def test_asynchronous_actors_update_from_every_rollout_as_it_comes(tmp_path):
    """`--switch-weights newest`: an actor waits only when it is AHEAD_CHUNKS rollouts ahead of
    its weights, the trainer makes one update from each actor's rollout (2 actors x 2 episodes x
    2 chunks = 8), within its lag bound, and each
    actor's episode end is one episode of the learning curve. The scenarios are the same as
    synchronous training's (they do not depend on the weights); the learning is not."""
    config_file = tmp_path / "train_config.json"
    config_file.write_text(json.dumps(CFG.to_dict()))
    spawner = Spawner(tmp_path, fresh_domain_id())
    try:
        run = spawner.formic("train_ros_async", "train-ros", "--train-config", str(config_file), "--actors", "2",
                             "--switch-weights", "newest", "--run-dir", str(tmp_path / "async"), "--episodes", "4",
                             "--domain-id", str(spawner.domain_id), "--timeout", "100", "--json", "--fresh",
                             limit_s=130)
        assert run.wait() == 0, run.output()[-3000:]
        result, output = run.json_line(), run.output()
    finally:
        spawner.reap_all()
    trainer = Trainer(CFG, tmp_path / "draws", resume=False, log=lambda _: None)
    seeds = []
    for episode in (0, 2):
        trainer.envs.reset(episode)
        seeds += [(episode, k, w.scenario.seed) for k, w in enumerate(trainer.envs.worlds)]
    trainer.close()
    assert [(e["episode"], e["actor"], e["seed"]) for e in result["episodes"]] == seeds
    assert all(e["missed_actions"] == 0 for e in result["episodes"])
    done = result["trainer"]
    assert (done["updates"], done["dropped"], done["lost"], done["version"]) == (8, 0, 0, 8)
    assert done["timing"]["timed_updates"] == 7 and set(done["timing"]) == {"timed_updates", "updates_per_s"}
    assert set(result["exit_codes"].values()) == {0}
    saved = read_checkpoint(tmp_path / "async" / "latest.pt")["progress"]
    assert (saved["episode"], saved["updates"]) == (4, 8)
    lags = [int(lag) for lag in re.findall(r"update \d+: .*?lag (\d+)", output)]  # the trainer's log lines
    assert len(lags) == 8 and max(lags) <= 2 * AHEAD_CHUNKS * 2  # the trainer's bound for 2 actors


def test_asynchronous_actors_go_on_with_a_restarted_trainer(tmp_path):
    """`formic trainer --actors 2 --asynchronous` SIGKILLed after its third update under two
    `formic actor --switch-weights newest` (4 episodes each), and started again on its run dir:
    it publishes its rollouts-taken counts under a new trainer id at once, the hosts count from
    there (so the AHEAD_CHUNKS bound does not hold them forever) and go on; the restarted
    trainer learns from their rollouts and both actors finish with no action missed."""
    spawner = Spawner(tmp_path, fresh_domain_id())
    try:
        trainer_args, actors, checkpoint = kill_trainer_at_update_3(
            tmp_path, spawner, ("--asynchronous",), ("--switch-weights", "newest"))
        saved = checkpoint["updates"]
        again = spawner.formic("trainer_again", *trainer_args, limit_s=90)
        assert [actor.wait() for actor in actors] == [0, 0], actors[0].output()[-3000:] + actors[1].output()[-3000:]
        os.killpg(again.pid, signal.SIGTERM)
        assert again.wait() == 0, again.output()[-3000:]
        result, log = again.json_line(), again.output()
        played = [actor.json_line()["episodes"] for actor in actors]
    finally:
        spawner.reap_all()
    assert "resumed from" in log and f"weights version {saved} published" in log
    assert result["updates"] >= 1 and result["version"] == saved + result["updates"]
    assert [len(episodes) for episodes in played] == [4, 4]
    assert all(e["missed_actions"] == 0 for episodes in played for e in episodes)
