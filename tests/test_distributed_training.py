"""Distributed training reproduces the in-process trainer.

A tiny setting (one 20x20 world of 4 agents, 32-step episodes, 16-step rollouts, the cpu
preset's network and algorithm) trained for two episodes by `formic train` in this process
and by `formic train-ros` (trainer node, world, learning host: real processes, own domain,
UDPv4) from the same settings and seeds: the same scenarios, the same food in every episode
and the same final weights, bit for bit. A third episode resumed from each run's checkpoint
matches too, and so do hosts that switch weights per episode when rollouts are whole episodes.
"""

from __future__ import annotations

import dataclasses
import json

import pytest

pytest.importorskip("rclpy")
pytest.importorskip("formic_interfaces.msg")
torch = pytest.importorskip("torch")

from ros_helpers import Spawner, fresh_domain_id  # noqa: E402

from formic_agent.checkpoint import read_checkpoint  # noqa: E402
from formic_trainer.config import load_train_config, make_config, train_config_from_dict  # noqa: E402
from formic_trainer.train import Trainer  # noqa: E402
from formic_trainer.worlds import MetaAgents, sample_scenarios, scenario_rng  # noqa: E402

pytestmark = pytest.mark.filterwarnings("ignore::UserWarning", "ignore:module 'sre_:DeprecationWarning")

CFG = make_config("cpu", seed=3, teams=(4,), world_sizes=((20, 20),), episode_steps=32, rollout_steps=16,
                  team_reward=0.25)


def quiet(_text: str) -> None:
    pass


def test_training_config_survives_its_json_form(tmp_path):
    path = tmp_path / "config.json"
    path.write_text(json.dumps(CFG.to_dict()))
    assert load_train_config(path) == CFG
    with pytest.raises(ValueError, match="unknown training settings: bogus"):
        train_config_from_dict({**CFG.to_dict(), "bogus": 1})


def test_a_training_world_imports_no_torch():
    """The world of a distributed run reads the training settings and draws their scenarios but
    runs no network: importing torch there cost every train-ros launch 1.5 s of a core."""
    import subprocess
    import sys

    code = ("import sys, formic_trainer.config, formic_trainer.worlds, formic_ros.world.training; "
            "print('torch' in sys.modules)")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "False"


def test_world_stream_draws_the_trainers_scenarios():
    """The world node's scenarios (sample_scenarios on each episode's scenario_rng) are
    MetaAgents' ones, also when a run resumes at a later episode."""
    cfg = make_config("cpu", teams=(6,), world_sizes=((20, 40),), obstacle_range=(0.0, 0.1), curriculum_start=1,
                      curriculum_end=3)
    envs = MetaAgents(cfg)
    for episode in range(4):
        envs.reset(episode)
        (scenario,), highway, _ = sample_scenarios(cfg, scenario_rng(cfg, episode), episode)
        assert scenario.to_json() == envs.worlds[0].scenario.to_json()
        assert highway == envs.highway
    envs = MetaAgents(cfg)
    envs.reset(7)
    assert sample_scenarios(cfg, scenario_rng(cfg, 7), 7)[0][0].to_json() == envs.worlds[0].scenario.to_json()


def in_process(run_dir, episodes: int, resume: bool, cfg=CFG) -> tuple[list[float], list[int], dict]:
    """`formic train` for ``episodes`` episodes: food and scenario seed of each, final weights."""
    trainer = Trainer(cfg, run_dir, resume=resume, log=quiet)
    food, seeds = [], []
    for _ in range(episodes):
        food.append(trainer.run_episode_set()["food_env0"])
        seeds.append(trainer.envs.worlds[0].scenario.seed)
    trainer.close()
    return food, seeds, trainer.net.state_dict()


def distributed(spawner: Spawner, config_file, run_dir, episodes: int, fresh: bool, *extra: str) -> dict:
    args = ["train-ros", "--train-config", str(config_file), "--run-dir", str(run_dir), "--episodes", str(episodes),
            "--domain-id", str(spawner.domain_id), "--timeout", "60", "--json", *extra] + (["--fresh"] if fresh else [])
    run = spawner.formic(f"train_ros_{episodes}_{fresh}", *args, limit_s=80)
    assert run.wait() == 0, run.output()[-3000:]
    return run.json_line()


def assert_same_weights(got: dict, want: dict) -> None:
    assert got.keys() == want.keys()
    for key in want:
        assert torch.equal(got[key], want[key]), key


def test_distributed_training_matches_the_in_process_trainer(tmp_path):
    torch.set_num_threads(1)
    food, seeds, weights = in_process(tmp_path / "in_process", 2, resume=False)
    more_food, more_seeds, more_weights = in_process(tmp_path / "in_process", 1, resume=True)
    assert sum(food + more_food) > 0, "the setting must collect food to compare"

    config_file = tmp_path / "train_config.json"
    config_file.write_text(json.dumps(CFG.to_dict()))
    run_dir = tmp_path / "distributed"
    spawner = Spawner(tmp_path, fresh_domain_id())
    try:
        result = distributed(spawner, config_file, run_dir, 2, fresh=True)
        episodes = result["episodes"]
        assert [e["episode"] for e in episodes] == [0, 1]
        assert [e["seed"] for e in episodes] == seeds
        assert [e["food"] for e in episodes] == food
        assert all(e["missed_actions"] == 0 and e["rejected_actions"] == {} for e in episodes)
        assert result["trainer"]["version"] == 4 and result["trainer"]["dropped"] == 0
        assert set(result["exit_codes"].values()) == {0}
        saved = read_checkpoint(run_dir / "latest.pt")
        assert saved["progress"]["episode"] == 2 and saved["progress"]["updates"] == 4
        assert_same_weights(saved["state_dict"], weights)

        resumed = distributed(spawner, config_file, run_dir, 1, fresh=False)
    finally:
        spawner.reap_all()
    assert resumed["first_episode"] == 2
    assert [(e["episode"], e["seed"], e["food"]) for e in resumed["episodes"]] == [(2, more_seeds[0], more_food[0])]
    assert_same_weights(read_checkpoint(run_dir / "latest.pt")["state_dict"], more_weights)


def test_switching_weights_per_episode_matches_with_whole_episode_rollouts(tmp_path):
    """Hosts that take new weights only at episode starts (the trainer learning while they
    play) act exactly as in one process when a rollout is a whole episode (the paper's way).
    Here with the own-action-feedback network and the filter being annealed (some agents act
    unfiltered in episode 1): the rollouts carry the extra inputs and the sampling masks."""
    torch.set_num_threads(1)
    cfg = dataclasses.replace(CFG, rollout_steps=CFG.episode_steps, network="cpu-feedback", filter_anneal_start=0,
                              filter_anneal_end=3)
    food, seeds, weights = in_process(tmp_path / "in_process", 2, resume=False, cfg=cfg)
    config_file = tmp_path / "train_config.json"
    config_file.write_text(json.dumps(cfg.to_dict()))
    spawner = Spawner(tmp_path, fresh_domain_id())
    try:
        result = distributed(spawner, config_file, tmp_path / "distributed", 2, True, "--switch-weights", "episode")
    finally:
        spawner.reap_all()
    assert [(e["seed"], e["food"]) for e in result["episodes"]] == list(zip(seeds, food))
    assert result["trainer"]["version"] == 2 and result["trainer"]["dropped"] == 0
    assert_same_weights(read_checkpoint(tmp_path / "distributed" / "latest.pt")["state_dict"], weights)
