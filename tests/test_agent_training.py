"""The network, checkpoints, the learned policy and the in-process trainer."""

from __future__ import annotations

import dataclasses
import json
import pickle
import subprocess
import sys
import time

import numpy as np
import pytest
import torch

from formic_agent.checkpoint import CheckpointError, load_network, save_checkpoint
from formic_runtime.episode import run_episode
from formic_agent.learned import LearnedPolicy
from formic_agent.inputs import NETWORK_PRESETS, NetworkConfig
from formic_agent.network import ForMICNet, count_parameters
from formic_agent.policy import AgentBatch
from formic_runtime.registry import make_policy
from formic_trainer.algorithm import policy_losses, sampling_mask, set_learning_rate
from formic_trainer.config import make_config, parse_overrides, reward_config
from formic_trainer.train import Trainer
from formic_trainer.worlds import MetaAgents, sample_scenarios, share_rewards
from formic_world import REWARD_PRESETS, World, WorldConfig, generate_scenario

TINY = dict(teams=(4,), world_sizes=((16, 16),), episode_steps=32, rollout_steps=16, threads=1)


def test_paper_network_has_the_papers_size_and_shapes():
    net = ForMICNet(NETWORK_PRESETS["paper"])
    assert 4.9e6 < count_parameters(net) < 5.0e6  # SPEC §5: 128/256/512, LSTM 512
    logits, values, (h, c) = net(torch.zeros(3, 2, 8, 11, 11), net.initial_state(2))
    assert logits.shape == (3, 2, 5) and values.shape == (3, 2) and h.shape == (1, 2, 512)


@pytest.mark.parametrize("view", [5, 11, 21])
def test_every_field_of_view_builds_and_runs(view):
    net = ForMICNet(NetworkConfig(conv1=4, conv2=4, fc=8, rnn=8, view_size=view))
    logits, _, _ = net(torch.zeros(1, 3, 8, view, view), net.initial_state(3))
    assert logits.shape == (1, 3, 5)


def test_checkpoint_round_trip_and_bad_files(tmp_path):
    net = ForMICNet(NETWORK_PRESETS["cpu-nest"])
    path = tmp_path / "model.pt"
    save_checkpoint(path, net, note="x")
    loaded, payload = load_network(path)
    assert loaded.config == net.config and payload["note"] == "x"
    for key, value in net.state_dict().items():
        assert torch.equal(loaded.state_dict()[key], value)
    assert not list(tmp_path.glob(".*tmp"))  # atomic write leaves no temporary file
    (tmp_path / "truncated.pt").write_bytes(path.read_bytes()[:1000])
    with pytest.raises(CheckpointError, match="not a readable"):
        load_network(tmp_path / "truncated.pt")
    (tmp_path / "code.pt").write_bytes(pickle.dumps(subprocess.Popen))  # a pickle naming code
    with pytest.raises(CheckpointError):
        load_network(tmp_path / "code.pt")
    torch.save({"format": "something else"}, tmp_path / "other.pt")
    with pytest.raises(CheckpointError, match="not a ForMIC checkpoint"):
        load_network(tmp_path / "other.pt")


def test_learned_actions_do_not_depend_on_how_agents_are_batched():
    """Sampling is keyed per (seed, step, agent): one batch or two halves act identically."""
    torch.manual_seed(0)
    net = ForMICNet(NETWORK_PRESETS["cpu-nest"])
    world = World(generate_scenario(WorldConfig(height=24, width=24, n_agents=8), 3))
    whole, halves = LearnedPolicy(net), LearnedPolicy(net)
    whole.reset(8, 5)
    halves.reset(8, 5)
    result = world.reset(world.scenario)
    for _ in range(20):
        batch = AgentBatch.from_world(world, observations=result.observations, action_mask=result.action_mask)
        a = whole.act(batch)
        first = AgentBatch.from_world(world, np.arange(4), result.observations, result.action_mask)
        second = AgentBatch.from_world(world, np.arange(4, 8), result.observations, result.action_mask)
        b = np.concatenate([halves.act(first), halves.act(second)])
        assert a.tolist() == b.tolist()
        result = world.step(a)


def test_trainer_resumes_exactly_where_its_checkpoint_left(tmp_path):
    cfg = make_config("cpu", **TINY)
    first = Trainer(cfg, tmp_path, resume=False, log=lambda *_: None)
    first.train(episodes=2)
    saved = {k: v.clone() for k, v in first.net.state_dict().items()}
    resumed = Trainer(cfg, tmp_path, resume=True, log=lambda *_: None)
    assert resumed.episode == 2 and resumed.updates == first.updates
    assert 0 < resumed.learner.cpu_seconds == first.learner.cpu_seconds  # the CPU clock travels too
    for key, value in saved.items():
        assert torch.equal(resumed.net.state_dict()[key], value)
    with pytest.raises(ValueError, match="different settings"):
        Trainer(make_config("cpu", **{**TINY, "lr": 1e-3}), tmp_path, resume=True, log=lambda *_: None)


@pytest.mark.parametrize("switches", [{}, {"network": "cpu-feedback", "learning_agents": 2, "weight_average": 0.9}])
def test_a_resumed_run_ends_where_the_uninterrupted_run_ends(tmp_path, switches):
    """Scenarios, sampling and minibatches are drawn from streams of the episode and update
    number, so 2 + (resume) + 2 episode sets give the weights (and their average) of 4."""
    cfg = make_config("cpu", **TINY, **switches)
    whole = Trainer(cfg, tmp_path / "whole", resume=False, log=lambda *_: None)
    whole.train(episodes=4)
    Trainer(cfg, tmp_path / "parts", resume=False, log=lambda *_: None).train(episodes=2)
    resumed = Trainer(cfg, tmp_path / "parts", resume=True, log=lambda *_: None)
    resumed.train(episodes=2)
    assert resumed.episode == whole.episode == 4
    nets = [(whole.net, resumed.net)]
    if cfg.weight_average:
        nets.append((whole.learner.averaged, resumed.learner.averaged))
    for a, b in nets:
        for key, value in a.state_dict().items():
            assert torch.equal(value, b.state_dict()[key]), key


def test_a_killed_training_process_resumes_from_its_last_checkpoint(tmp_path):
    """SIGKILL mid-run loses nothing before the last checkpoint; the run then continues."""
    run_dir = tmp_path / "run"
    sets = ["--set", "teams=4", "--set", "episode_steps=32", "--set", "rollout_steps=16", "--set", "threads=1"]
    base = [sys.executable, "-m", "formic_cli.main", "train", "--preset", "cpu", "--run-dir", str(run_dir), *sets]
    process = subprocess.Popen([*base, "--episodes", "1000"], stdout=subprocess.PIPE, stderr=subprocess.STDOUT)
    try:
        start = time.monotonic()
        while not (run_dir / "latest.pt").exists() and time.monotonic() - start < 120:
            time.sleep(0.2)
        assert (run_dir / "latest.pt").exists(), "no checkpoint written"
        process.kill()
    finally:
        process.kill()
        process.wait(timeout=30)
    before = torch.load(run_dir / "latest.pt", weights_only=True)["progress"]["episode"]
    assert before >= 1
    done = subprocess.run([*base, "--episodes", "1"], capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stdout + done.stderr
    assert f"resumed from {run_dir / 'latest.pt'}: episode {before}" in done.stdout
    after = torch.load(run_dir / "latest.pt", weights_only=True)["progress"]["episode"]
    assert after == before + 1


def test_ctrl_c_ends_a_training_run_with_the_command_that_resumes_it(tmp_path):
    import signal

    run_dir = tmp_path / "run"
    sets = ["--set", "teams=4", "--set", "episode_steps=32", "--set", "rollout_steps=16", "--set", "threads=1"]
    process = subprocess.Popen([sys.executable, "-m", "formic_cli.main", "train", "--preset", "cpu", "--run-dir",
                                str(run_dir), *sets, "--episodes", "1000"], stdout=subprocess.PIPE,
                               stderr=subprocess.STDOUT, text=True,
                               preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))
    try:
        start = time.monotonic()
        while not (run_dir / "latest.pt").exists() and time.monotonic() - start < 120:
            time.sleep(0.2)
        process.send_signal(signal.SIGINT)
        output, _ = process.communicate(timeout=60)
    finally:
        process.kill()
        process.wait(timeout=30)
    assert process.returncode == 130, output[-2000:]
    lines = output.splitlines()
    assert lines[-1] == f"interrupted: rerun the same command to resume from {run_dir / 'latest.pt'}"
    assert "Traceback" not in output and "Aborted" not in output
    # the set in progress ended and was saved: the checkpoint is the last episode the log printed
    assert any(line.startswith("stop requested: the episode set in progress ends") for line in lines)
    episode = torch.load(run_dir / "latest.pt", weights_only=True)["progress"]["episode"]
    assert lines[-2] == f"stopped at episode {episode}, its checkpoint saved"
    assert [line for line in lines if line.startswith("ep ")][-1].split("|")[0] == f"ep {episode:6d} "


def _signal_during_the_second_set(trainer: Trainer, signals: int) -> None:
    """``signals`` SIGTERMs to this process halfway through the trainer's second episode set."""
    import os
    import signal

    step, calls = trainer.envs.step, []

    def step_and_signal(actions):
        calls.append(1)
        if len(calls) == trainer.cfg.episode_steps * 3 // 2:
            for _ in range(signals):
                os.kill(os.getpid(), signal.SIGTERM)
        return step(actions)

    trainer.envs.step = step_and_signal


def test_a_stop_signal_ends_training_after_the_set_in_progress_and_the_run_resumes_exactly(tmp_path):
    """The set under way when the signal comes is finished and saved (here the only checkpoint,
    as checkpoint_every is larger than the run); resumed, the run ends with the weights of one
    never stopped."""
    cfg = make_config("cpu", **TINY, checkpoint_every=100)
    lines = []
    stopped = Trainer(cfg, tmp_path / "parts", resume=False, log=lines.append)
    _signal_during_the_second_set(stopped, signals=1)
    with pytest.raises(KeyboardInterrupt):
        stopped.train(episodes=5)
    assert stopped.episode == 2 and lines[-1] == "stopped at episode 2, its checkpoint saved"
    resumed = Trainer(cfg, tmp_path / "parts", resume=True, log=lambda *_: None)
    assert resumed.episode == 2
    resumed.train(episodes=1)
    whole = Trainer(cfg, tmp_path / "whole", resume=False, log=lambda *_: None)
    whole.train(episodes=3)
    for key, value in whole.net.state_dict().items():
        assert torch.equal(value, resumed.net.state_dict()[key]), key


def test_a_second_stop_signal_interrupts_training_at_once(tmp_path):
    cfg = make_config("cpu", **TINY, checkpoint_every=100)
    trainer = Trainer(cfg, tmp_path, resume=False, log=lambda *_: None)
    _signal_during_the_second_set(trainer, signals=2)
    with pytest.raises(KeyboardInterrupt):
        trainer.train(episodes=5)
    assert trainer.episode == 1 and not (tmp_path / "latest.pt").exists()


def test_overrides_are_typed_and_checked():
    assert parse_overrides(["lr=0.001", "pheromones=false", "teams=8,16", "network=cpu"]) == {
        "lr": 0.001, "pheromones": False, "teams": (8, 16), "network": "cpu"}
    with pytest.raises(ValueError, match="TrainConfig field"):
        parse_overrides(["nonsense=1"])
    with pytest.raises(ValueError, match="true/false"):
        parse_overrides(["pheromones=maybe"])
    assert parse_overrides(["world_sizes=40-96,128-128"]) == {"world_sizes": ((40, 96), (128, 128))}
    with pytest.raises(ValueError, match="MIN-MAX"):
        parse_overrides(["world_sizes=40:96"])
    with pytest.raises(ValueError, match="cannot be set"):
        parse_overrides(["obstacle_range=0,1"])


def test_reward_overrides_replace_single_rewards_of_the_preset_in_the_training_worlds():
    cfg = make_config("cpu", rewards="reference", teams=(4,), world_sizes=((20, 20),),
                      **parse_overrides(["reward_overrides=deposit=10, blocked=-0.25"]))
    expected = dataclasses.replace(REWARD_PRESETS["reference"], deposit=10.0, blocked=-0.25)
    assert reward_config(cfg) == expected and reward_config(make_config("cpu")) == REWARD_PRESETS["paper"]
    scenarios, _, _ = sample_scenarios(cfg, np.random.default_rng(0), episode=0)
    assert scenarios[0].config.rewards == expected
    with pytest.raises(ValueError, match="reward field"):
        make_config("cpu", reward_overrides="deposits=10")
    with pytest.raises(ValueError, match="needs a number"):
        make_config("cpu", reward_overrides="deposit=ten")


def test_formic_sim_json_matches_the_in_process_episode(tmp_path):
    out = subprocess.run(
        [sys.executable, "-m", "formic_cli.main", "sim", "--policy", "random", "--agents", "6", "--size", "24",
         "--steps", "60", "--seed", "4", "--out", str(tmp_path), "--json"],
        capture_output=True, text=True, timeout=120,
    )
    assert out.returncode == 0, out.stderr
    summary = json.loads(out.stdout)
    scenario = generate_scenario(WorldConfig(height=24, width=24, n_agents=6, episode_steps=60), 4)
    result = run_episode(scenario, "random")
    assert summary["food"] == result.food
    assert summary["state_digest"] == result.world.state_digest()
    assert (tmp_path / "final.png").exists()
    assert len(summary["per_agent"]["delivered"]) == 6


def test_missing_model_is_a_clear_error(tmp_path):
    out = subprocess.run(
        [sys.executable, "-m", "formic_cli.main", "sim", "--policy", "formic", "--model", str(tmp_path / "none.pt"),
         "--agents", "4", "--size", "16", "--steps", "5", "--out", str(tmp_path)],
        capture_output=True, text=True, timeout=120,
    )
    assert out.returncode != 0 and "none.pt" in out.stderr


def test_team_reward_mixes_each_reward_with_the_team_mean():
    rewards = np.array([10.0, -0.05, -0.05, -1.0])
    assert share_rewards(rewards, 0.0) is rewards  # off: the paper's individual rewards untouched
    team_mean = np.float32(rewards.astype(np.float32).mean())
    mixed = share_rewards(rewards, 0.5)
    assert mixed.dtype == np.float32  # as the ROS observation messages carry rewards
    np.testing.assert_allclose(mixed, 0.5 * rewards + 0.5 * team_mean, rtol=1e-6)
    np.testing.assert_allclose(share_rewards(rewards, 1.0), np.full(4, team_mean), rtol=1e-6)
    assert mixed.sum() == pytest.approx(rewards.sum(), rel=1e-6)  # sharing moves reward, never adds it


def test_learning_rate_warms_up_linearly_over_the_first_updates():
    optimizer = torch.optim.Adam([torch.nn.Parameter(torch.zeros(1))], lr=1.0)
    cfg = make_config("cpu", lr=0.001, lr_warmup=4)
    rates = []
    for updates in range(6):
        set_learning_rate(optimizer, cfg, updates)
        rates.append(optimizer.param_groups[0]["lr"])
    assert rates == pytest.approx([0.00025, 0.0005, 0.00075, 0.001, 0.001, 0.001])
    set_learning_rate(optimizer, make_config("cpu", lr=0.001), 0)  # off by default
    assert optimizer.param_groups[0]["lr"] == 0.001


def test_demonstrator_sees_what_the_learners_see_and_targets_loaded_agents_near_the_nest():
    cfg = make_config("cpu", teams=(24,), world_sizes=((24, 24),), imitate="csaf11", imitation_radius=3,
                      imitation_agents="all")
    envs = MetaAgents(cfg)
    envs.reset(0)
    world = envs.worlds[0]
    twin = make_policy("csaf11")  # the same demonstrator, driven by hand
    twin.reset(24, world.scenario.seed)
    rng = np.random.default_rng(0)
    for _ in range(12):
        frame = envs.observe()
        targets, wanted = envs.demonstrations()
        np.testing.assert_array_equal(targets, twin.act(AgentBatch.from_world(
            world, observations=frame.observations, action_mask=frame.action_mask)))
        near = np.abs(world.pos - 11.5).max(axis=1) <= 3
        np.testing.assert_array_equal(wanted, near & ~world.queued)
        assert wanted.any()
        envs.step(rng.integers(0, 5, 24))
    envs.cfg = dataclasses.replace(cfg, imitation_agents="loaded")
    world.load[::2] = world.load_full  # half the team carrying
    envs.observe()
    _, wanted = envs.demonstrations()
    near = np.abs(world.pos - 11.5).max(axis=1) <= 3
    np.testing.assert_array_equal(wanted, near & world.carrying & ~world.queued)
    assert wanted.any() and not wanted[1::2].any()


def _loss_batch(T: int, B: int, gen: torch.Generator, **fields) -> dict[str, torch.Tensor]:
    """A batch for policy_losses (the cpu network's shapes): random observations, actions,
    returns and advantages, every action valid and every step free unless ``fields`` say otherwise."""
    return {
        "observations": torch.rand(T, B, 8, 11, 11, generator=gen), "extra_inputs": torch.zeros(T, B, 4),
        "h0": torch.zeros(1, B, 64), "c0": torch.zeros(1, B, 64),
        "actions": torch.randint(0, 5, (T, B), generator=gen), "logprobs": torch.full((T, B), -1.6),
        "train_mask": torch.ones(T, B, 5, dtype=torch.bool), "sample_mask": torch.ones(T, B, 5, dtype=torch.bool),
        "any_valid": torch.ones(T, B),
        "loss_mask": torch.ones(T, B), "value_mask": torch.ones(T, B), "returns": torch.rand(T, B, generator=gen),
        "advantages": torch.rand(T, B, generator=gen), **fields,
    }


def test_imitation_loss_is_the_cross_entropy_of_the_demonstrators_actions():
    torch.manual_seed(0)
    cfg = make_config("cpu", imitate="csaf11", imitation_coef=0.5)
    net = ForMICNet(NETWORK_PRESETS["cpu"])
    T, B = 3, 4
    gen = torch.Generator().manual_seed(1)
    batch = _loss_batch(T, B, gen, expert_actions=torch.randint(0, 5, (T, B), generator=gen),
                        imitation_mask=torch.tensor([[1.0, 0, 1, 0]] * T))
    terms = policy_losses(net, cfg, batch)
    logits, _, _ = net(batch["observations"], (batch["h0"], batch["c0"]), batch["extra_inputs"])
    ce = torch.nn.functional.cross_entropy(logits[:, [0, 2]].reshape(-1, 5), batch["expert_actions"][:, [0, 2]].reshape(-1))
    assert terms["imitation"].item() == pytest.approx(ce.item(), rel=1e-5)
    without = policy_losses(net, cfg, {k: v for k, v in batch.items() if k not in ("expert_actions", "imitation_mask")})
    assert terms["loss"].item() == pytest.approx(without["loss"].item() + 0.5 * ce.item(), rel=1e-5)


@pytest.mark.parametrize("queued_value_loss", [False, True])
def test_queued_steps_train_the_critic_only_with_queued_value_loss(queued_value_loss):
    """Queued steps (loss_mask 0) stay out of the policy, entropy and valid terms either way; the
    value term covers them only with queued_value_loss, still excluding value_mask's steps."""
    torch.manual_seed(0)
    cfg = make_config("cpu", queued_value_loss=queued_value_loss)
    net = ForMICNet(NETWORK_PRESETS["cpu"])
    T, B = 4, 3
    gen = torch.Generator().manual_seed(2)
    loss_mask = torch.tensor([[1.0, 1, 0], [0, 1, 1], [1, 0, 1], [1, 1, 1]])  # 0: the agent is queued
    value_mask = torch.tensor([[1.0, 1, 1], [1, 1, 1], [1, 1, 0], [1, 1, 1]])
    batch = _loss_batch(T, B, gen, loss_mask=loss_mask, value_mask=value_mask)
    terms = policy_losses(net, cfg, batch)
    _, values, _ = net(batch["observations"], (batch["h0"], batch["c0"]), batch["extra_inputs"])
    err = 0.5 * (values - batch["returns"]) ** 2
    expected = value_mask if queued_value_loss else loss_mask * value_mask
    assert terms["value"].item() == pytest.approx(((err * expected).sum() / expected.sum()).item(), rel=1e-5)
    plain = policy_losses(net, make_config("cpu"), batch)
    for key in ("policy", "entropy", "valid"):
        assert terms[key].item() == pytest.approx(plain[key].item(), rel=1e-6)
    assert make_config("cpu").queued_value_loss is False and make_config("paper").queued_value_loss is False


def test_join_validity_loss_is_the_bce_of_the_join_logit_on_free_steps():
    torch.manual_seed(0)
    net = ForMICNet(NETWORK_PRESETS["cpu"])
    T, B = 3, 4
    gen = torch.Generator().manual_seed(3)
    train_mask = torch.ones(T, B, 5, dtype=torch.bool)
    train_mask[..., 4] = torch.tensor([[True, False, False, True], [False, False, True, False], [True, True, False, False]])
    loss_mask = torch.tensor([[1.0, 1, 0, 1], [1, 0, 1, 1], [1, 1, 1, 0]])
    batch = _loss_batch(T, B, gen, train_mask=train_mask, loss_mask=loss_mask)
    terms = policy_losses(net, make_config("cpu", valid_join_coef=0.5), batch)
    logits, _, _ = net(batch["observations"], (batch["h0"], batch["c0"]), batch["extra_inputs"])
    bce = torch.nn.functional.binary_cross_entropy_with_logits(logits[..., 4], train_mask[..., 4].float(), reduction="none")
    assert terms["valid_join"].item() == pytest.approx(((bce * loss_mask).sum() / loss_mask.sum()).item(), rel=1e-5)
    plain = policy_losses(net, make_config("cpu"), batch)
    assert "valid_join" not in plain
    assert terms["loss"].item() == pytest.approx(plain["loss"].item() + 0.5 * terms["valid_join"].item(), rel=1e-5)


def test_modes_are_checked_when_a_config_is_made():
    with pytest.raises(ValueError, match="action_filter must be one of 'replace', 'mask', 'none', not 'mask2'"):
        make_config("cpu", **parse_overrides(["action_filter=mask2"]))
    with pytest.raises(ValueError, match="valid_loss must be one of 'bce', 'mass', not 'bcee'"):
        make_config("cpu", valid_loss="bcee")
    with pytest.raises(ValueError, match="network must be one of"):
        make_config("cpu", network="cpu-nets")


def test_a_committed_checkpoint_resumes_weights_optimiser_and_counters(tmp_path):
    """A run directory written before the trainer was split into actor and learner resumes:
    its weights, optimiser state and counters, and it learns on from there."""
    import shutil
    from pathlib import Path

    from formic_agent.checkpoint import read_checkpoint
    from formic_trainer.actor import Actor
    from formic_trainer.config import load_train_config
    from formic_trainer.learner import Learner

    stored = Path(__file__).resolve().parents[1] / "models" / "training" / "cpu-v3"
    for name in ("latest.pt", "config.json"):
        shutil.copy(stored / name, tmp_path / name)
    cfg = load_train_config(tmp_path / "config.json")
    payload = read_checkpoint(tmp_path / "latest.pt")
    learner = Learner(cfg, tmp_path, resume=True, log=lambda *_: None)
    progress = payload["progress"]
    assert (learner.episode, learner.updates, learner.env_steps) == (
        progress["episode"], progress["updates"], progress["env_steps"])
    for key, value in payload["state_dict"].items():
        assert torch.equal(learner.net.state_dict()[key], value)
    assert learner.optimizer.state_dict()["state"], "the optimiser's moments are restored"
    small = dataclasses.replace(cfg, teams=(4,), world_sizes=((16, 16),), episode_steps=8, rollout_steps=8)
    envs = MetaAgents(small)
    envs.reset(learner.episode)
    actor = Actor(small, learner.net, np.arange(4))
    actor.start_episode(learner.episode)
    frame = envs.observe()
    for _ in range(8):
        envs.step(actor.act(frame))
        frame = envs.observe()
        actor.reward(frame.rewards)
    assert np.isfinite(learner.learn(actor.rollout(frame, done=True, food=0.0))["loss"])
    # a checkpoint from before the CPU clock resumes with its wall seconds in its place
    assert "cpu_seconds" not in progress and learner.cpu_seconds == progress["seconds"]
    learner.end_episodes(1, {}, seconds=2.0, cpu_seconds=1.5)
    learner.close()
    saved = read_checkpoint(tmp_path / "latest.pt")["progress"]
    assert (saved["episode"], saved["updates"]) == (progress["episode"] + 1, progress["updates"] + 1)
    assert (saved["seconds"], saved["cpu_seconds"]) == (progress["seconds"] + 2.0, progress["seconds"] + 1.5)


@pytest.mark.parametrize("mask_join", [False, True])
def test_sampling_mask_is_a_new_array_the_actor_may_widen(mask_join):
    """Annealing widens the sampling mask of unfiltered agents in place; the valid-action
    target it was derived from must stay as it was (with mask_join it once was the same array)."""
    cfg = make_config("cpu", mask_join=mask_join)
    train_mask = np.array([[True, False, False, False, False], [False, True, False, False, True]])
    target = train_mask.copy()
    allowed = sampling_mask(cfg, train_mask)
    allowed[0] = True
    assert np.array_equal(train_mask, target)
    assert allowed[1, 4] and allowed[1].sum() == 2
    assert bool(sampling_mask(cfg, train_mask)[0, 4]) is not mask_join


def test_action_feedback_is_the_agents_own_last_action_and_whether_it_took_effect():
    """Exact features on a hand-built world: a free move, a move into another agent, JOIN away
    from every queue, JOIN onto a cache queue, a queued agent (its action is ignored)."""
    from conftest import build_world, agent
    from formic_agent.inputs import ActionFeedback, N_FEEDBACK_INPUTS
    from formic_world.geometry import EAST, JOIN

    world = build_world([agent(2, 2), agent(3, 3), agent(3, 4), agent(6, 7, loaded=True),
                         agent(7, 6, loaded=True, cache_queue=0)])
    assert world.queued.tolist() == [False, False, False, False, True]
    feedback = ActionFeedback(5)
    ids = np.arange(5)
    assert not feedback.features(ids, world.pos, world.queued).any()  # nothing done yet
    actions = np.array([EAST, EAST, JOIN, JOIN, EAST])
    feedback.record(ids, actions, world.pos.copy(), world.queued.copy())
    world.step(actions)
    assert world.queued.tolist() == [False, False, False, True, True]
    got = feedback.features(ids, world.pos, world.queued)
    want = np.zeros((5, N_FEEDBACK_INPUTS), dtype=np.float32)
    want[0, [EAST, 5]] = 1  # moved east
    want[1, EAST] = 1  # east was taken by agent 2: no effect
    want[2, JOIN] = 1  # no queue entry near: no effect
    want[3, [JOIN, 5]] = 1  # joined the north-east cache queue
    assert got.tolist() == want.tolist()  # agent 4 was queued: its action was ignored
    feedback.forget(np.array([0]))
    assert not feedback.features(ids, world.pos, world.queued)[0].any()


def test_training_frames_and_the_learned_policy_give_the_same_action_feedback():
    """The trainer's worlds and the evaluation policy wire the feedback the same way."""
    torch.manual_seed(1)
    cfg = make_config("cpu", network="cpu-feedback", seed=2, **TINY)
    envs = MetaAgents(cfg)
    envs.reset(0)
    policy = LearnedPolicy(ForMICNet(NETWORK_PRESETS["cpu-feedback"]))
    world = envs.worlds[0]
    policy.reset(world.config.n_agents, 7)
    effective = 0
    for _ in range(24):
        frame = envs.observe()
        batch = AgentBatch.from_world(world, observations=frame.observations, action_mask=frame.action_mask)
        want = policy.feedback.features(batch.agent_ids, batch.positions, batch.queued)
        assert frame.extra_inputs[:, -want.shape[1]:].tolist() == want.tolist()
        effective += int(want[:, -1].sum())
        envs.step(policy.act(batch))
    assert effective > 0


def test_widening_a_network_with_feedback_inputs_keeps_what_it_does():
    from formic_agent.checkpoint import initialise_from
    from formic_agent.inputs import N_EXTRA_INPUTS

    torch.manual_seed(3)
    source, widened = ForMICNet(NETWORK_PRESETS["cpu-nest"]), ForMICNet(
        dataclasses.replace(NETWORK_PRESETS["cpu-nest"], action_input=True))
    initialise_from(widened, source)
    obs, extra = torch.rand(3, 2, 8, 11, 11), torch.rand(3, 2, N_EXTRA_INPUTS)
    state = source.initial_state(2)
    for a, b in zip(source(obs, state, extra), widened(obs, state, extra)):
        assert torch.equal(a, b) if isinstance(a, torch.Tensor) else all(map(torch.equal, a, b))
    with pytest.raises(CheckpointError, match="only extra inputs may be added"):
        initialise_from(ForMICNet(NETWORK_PRESETS["cpu"]), source)
    with pytest.raises(CheckpointError, match="only extra inputs may be added"):
        initialise_from(ForMICNet(NETWORK_PRESETS["paper"]), ForMICNet(NETWORK_PRESETS["cpu"]))


def test_the_weight_average_follows_each_update_and_survives_a_resume(tmp_path):
    """weight_average=d: after each update averaged = d*averaged + (1-d)*weights, written as
    averaged.pt (a model) at each checkpoint and restored on resume."""
    from formic_trainer.learner import Learner

    cfg = make_config("cpu", **TINY, weight_average=0.75)
    trainer = Trainer(cfg, tmp_path, resume=False, log=lambda *_: None)
    expected = {k: v.clone() for k, v in trainer.net.state_dict().items()}  # it starts at the weights
    learner = trainer.learner
    original = learner.learn

    def learn_and_track(*args, **kwargs):
        stats = original(*args, **kwargs)
        for key, value in learner.net.state_dict().items():
            expected[key] = 0.75 * expected[key] + 0.25 * value if value.is_floating_point() else value.clone()
        return stats

    learner.learn = learn_and_track
    trainer.train(episodes=2)
    assert learner.updates >= 2
    for key, value in learner.averaged.state_dict().items():
        torch.testing.assert_close(value, expected[key])
    assert not all(torch.equal(value, learner.net.state_dict()[key])
                   for key, value in learner.averaged.state_dict().items() if value.is_floating_point())
    model, payload = load_network(tmp_path / "averaged.pt")  # what --model loads
    assert payload["weight_average"] == 0.75 and payload["progress"]["updates"] == learner.updates
    for key, value in model.state_dict().items():
        assert torch.equal(value, learner.averaged.state_dict()[key])
    resumed = Learner(cfg, tmp_path, resume=True, log=lambda *_: None)
    for key, value in resumed.averaged.state_dict().items():
        assert torch.equal(value, learner.averaged.state_dict()[key])
    off = Learner(make_config("cpu", **TINY), tmp_path / "off", resume=False, log=lambda *_: None)
    off.save()
    assert off.averaged is None and not (tmp_path / "off" / "averaged.pt").exists()
    with pytest.raises(ValueError, match="weight_average"):
        make_config("cpu", weight_average=1.0)


def test_fewer_learning_agents_than_minibatches_still_train(tmp_path):
    """Two learners and four minibatches: each minibatch holds one learner's sequence (the split
    used to leave empty minibatches, which crashed the network)."""
    cfg = make_config("cpu", **TINY, learning_agents=2)
    assert cfg.minibatches > 2
    trainer = Trainer(cfg, tmp_path, resume=False, log=lambda *_: None)
    before = {k: v.clone() for k, v in trainer.net.state_dict().items()}
    trainer.train(episodes=1)
    assert trainer.updates == 2
    assert any(not torch.equal(before[k], v) for k, v in trainer.net.state_dict().items())


def test_actor_streams_of_other_seeds_episodes_or_agents_differ():
    """No (seed, episode, first agent) shares its sampler or numpy stream with another."""
    from formic_trainer.actor import actor_streams

    keys = [(8, 4, 0), (9, 3, 0), (8, 3, 1), (8, 4, 1), (9, 4, 0)]
    draws = []
    for seed, episode, agent in keys:
        sampler, stream = actor_streams(make_config("cpu", seed=seed), episode, agent)
        draws.append((tuple(torch.rand(4, generator=sampler).tolist()), tuple(stream.random(4))))
    assert len({d[0] for d in draws}) == len({d[1] for d in draws}) == len(keys)
    again = actor_streams(make_config("cpu", seed=8), 4, 0)
    assert tuple(torch.rand(4, generator=again[0]).tolist()) == draws[0][0]
