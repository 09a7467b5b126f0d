"""The trainer node learns exactly what the in-process trainer learns from the same rollouts.

A chunk of experience is collected in this process with the in-process trainer's machinery
(its worlds and actor); the reference is the in-process learner's update on that chunk. A trainer node in
its own process receives the same chunk as a Rollout message and must broadcast weights equal
to the reference, parameter for parameter, with increasing versions, and checkpoint them.
"""

from __future__ import annotations

import copy
import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("rclpy")
pytest.importorskip("formic_interfaces.msg")
torch = pytest.importorskip("torch")

from formic_agent.checkpoint import CheckpointError, read_checkpoint  # noqa: E402
from formic_agent.learned import LearnedPolicy  # noqa: E402
from formic_agent.network import N_EXTRA_INPUTS  # noqa: E402
from formic_ros.convert import decode_rollout as rollout_arrays  # noqa: E402
from formic_ros.learning_host import rollout_message  # noqa: E402
from formic_ros.trainer_node import apply_weights  # noqa: E402
from formic_ros.trainer_node import RemoteLearner  # noqa: E402
from formic_trainer.actor import Actor  # noqa: E402
from formic_trainer.config import make_config  # noqa: E402
from formic_trainer.learner import Learner  # noqa: E402
from formic_trainer.worlds import MetaAgents  # noqa: E402

pytestmark = pytest.mark.filterwarnings("ignore::UserWarning", "ignore:module 'sre_:DeprecationWarning")

ROOT = Path(__file__).resolve().parents[1]
DOMAIN_ID = 100 + os.getpid() % 40
STEPS = 8
UPDATE_FIELDS = {"epochs": 2, "minibatches": 2, "rollout_steps": STEPS, "episode_steps": STEPS}
CFG = make_config("cpu", teams=(4,), world_sizes=((16, 16),), **UPDATE_FIELDS)


def quiet(_text: str) -> None:
    pass


def collect(net, episode: int) -> dict[str, np.ndarray]:
    """One chunk (a whole episode) from the training worlds and the actor, as ``formic train``
    collects it: the rollout with the behaviour policy's outputs."""
    envs = MetaAgents(CFG)
    envs.reset(episode)
    actor = Actor(CFG, net, np.arange(envs.n_agents))
    actor.start_episode(episode)
    frame = envs.observe()
    for _ in range(STEPS):
        rewards, _ = envs.step(actor.act(frame))
        actor.reward(rewards)
        frame = envs.observe()
    return actor.rollout(frame.obs, frame.extra)


def message(rollout: dict[str, np.ndarray], episode: int):
    """What a learning host sends (:func:`formic_ros.learning_host.rollout_message`)."""
    return rollout_message(rollout, weights_version=0, host="test-host", episode=episode, food=0.0)


def snapshot(net) -> dict[str, torch.Tensor]:
    return {k: v.detach().clone() for k, v in net.state_dict().items()}


def assert_same_weights(got: dict, want: dict) -> None:
    assert got.keys() == want.keys()
    for key in want:
        assert torch.equal(got[key], want[key]), key


@pytest.fixture(scope="module")
def experience(tmp_path_factory):
    """Two chunks collected with the initial weights (version 0), and the reference weights
    after the in-process learner's updates on the first, then the second."""
    torch.set_num_threads(1)
    tmp = tmp_path_factory.mktemp("trainer")
    reference = Learner(CFG, tmp / "reference", resume=False, log=quiet)
    actor_net = copy.deepcopy(reference.net)
    chunks = [collect(actor_net, episode) for episode in (0, 1)]
    versions = [snapshot(reference.net)]
    for rollout in chunks:
        reference.learn(rollout)
        versions.append(snapshot(reference.net))
    reference.writer.close()
    return {"tmp": tmp, "chunks": chunks, "versions": versions}


def test_rollout_message_round_trip(experience):
    rollout = experience["chunks"][0]
    msg = message(rollout, 0)
    assert (msg.n_steps, msg.n_agents, msg.channels, msg.size) == (STEPS, 4, 8, 11)
    got = rollout_arrays(msg)
    assert set(got) == {"agent_ids", "obs", "actions", "rewards", "train_mask", "loss_mask", "value_mask",
                        "sample_mask", "extra"}
    for key in got:
        assert np.array_equal(got[key], rollout[key]), key
    assert got["extra"].shape[-1] == N_EXTRA_INPUTS  # convert.EXTRA_INPUT_COUNT, restated without torch
    msg.rewards = msg.rewards[:-1]
    with pytest.raises(ValueError, match="Rollout.rewards"):
        rollout_arrays(msg)


def test_learner_recomputes_the_behaviour_outputs_and_drops_stale_rollouts(experience, tmp_path):
    """In process: the remote learner's update equals the reference; a rollout from weights it
    no longer keeps is dropped."""
    first, second = (rollout_arrays(message(rollout, episode)) for episode, rollout in enumerate(experience["chunks"]))
    learner = RemoteLearner(CFG, tmp_path / "run", resume=False, max_lag=0, log=quiet)
    assert learner.learn(first, weights_version=0, host="h", episode=0) is not None
    assert learner.version == 1
    assert_same_weights(snapshot(learner.learner.net), experience["versions"][1])
    assert learner.learn(second, weights_version=0, host="h", episode=1) is None
    assert learner.dropped == 1 and learner.version == 1
    learner.close()


def test_trainer_node_broadcasts_the_in_process_update(experience, monkeypatch):
    import rclpy
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy

    from formic_interfaces.msg import Rollout, Weights

    run_dir = experience["tmp"] / "node"
    overrides = [arg for key, value in {**UPDATE_FIELDS, "teams": 4}.items() for arg in ("--set", f"{key}={value}")]
    env = dict(os.environ, ROS_DOMAIN_ID=str(DOMAIN_ID), FASTDDS_BUILTIN_TRANSPORTS="UDPv4",
               ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST", PYTHONUNBUFFERED="1")
    node_proc = subprocess.Popen(
        [sys.executable, "-m", "formic_cli.main", "trainer", "--run-dir", str(run_dir), "--fresh", "--preset", "cpu",
         *overrides, "--max-updates", "2", "--json"],
        env=env, cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, start_new_session=True,
    )
    for key in ("ROS_DOMAIN_ID", "FASTDDS_BUILTIN_TRANSPORTS", "ROS_AUTOMATIC_DISCOVERY_RANGE"):
        monkeypatch.setenv(key, env[key])
    context = rclpy.Context()
    rclpy.init(context=context, domain_id=DOMAIN_ID)
    received: dict[int, Weights] = {}
    try:
        node = rclpy.create_node("host", namespace="/formic", context=context)
        executor = SingleThreadedExecutor(context=context)
        executor.add_node(node)
        reliable = ReliabilityPolicy.RELIABLE
        latched = QoSProfile(depth=1, reliability=reliable, durability=DurabilityPolicy.TRANSIENT_LOCAL)
        node.create_subscription(Weights, "weights", lambda m: received.setdefault(m.version, m), latched)
        rollouts = node.create_publisher(Rollout, "rollouts", QoSProfile(depth=16, reliability=reliable))

        def wait_for(condition, seconds: float) -> None:
            deadline = time.monotonic() + seconds
            while not condition() and time.monotonic() < deadline and node_proc.poll() is None:
                executor.spin_once(timeout_sec=0.05)
            assert condition(), node_proc.stderr.read() if node_proc.poll() is not None else "timed out"

        wait_for(lambda: 0 in received and rollouts.get_subscription_count() > 0, 60)
        for version, rollout in enumerate(experience["chunks"], start=1):
            rollouts.publish(message(rollout, version - 1))
            wait_for(lambda v=version: v in received, 30)
        out, err = node_proc.communicate(timeout=30)
    finally:
        rclpy.shutdown(context=context)
        if node_proc.poll() is None:
            os.killpg(node_proc.pid, signal.SIGKILL)
            node_proc.communicate()
    assert node_proc.returncode == 0, err
    assert sorted(received) == [0, 1, 2]
    for version, weights in received.items():
        payload = read_checkpoint(bytes(weights.data))
        assert_same_weights(payload["state_dict"], experience["versions"][version])
        assert json.loads(weights.model_config_json) == payload["network"]
        assert len(weights.checkpoint_id) == 12
    assert json.loads(out.strip().splitlines()[-1])["version"] == 2
    saved = read_checkpoint(run_dir / "latest.pt")
    assert saved["progress"]["updates"] == 2 and saved["progress"]["episode"] == 2
    assert_same_weights(saved["state_dict"], experience["versions"][2])

    policy = LearnedPolicy.from_checkpoint(run_dir / "latest.pt")
    policy.load_state_dict(experience["versions"][0])
    assert apply_weights(policy, received[2]) == 2
    assert_same_weights(snapshot(policy.net), experience["versions"][2])
    wrong = Weights(version=3, data=read_bytes_of_other_network())
    with pytest.raises(CheckpointError, match="do not fit"):
        apply_weights(policy, wrong)


def read_bytes_of_other_network() -> bytes:
    from formic_agent.checkpoint import state_dict_bytes
    from formic_agent.network import NETWORK_PRESETS, ForMICNet

    return state_dict_bytes(ForMICNet(NETWORK_PRESETS["cpu-nest"]))
