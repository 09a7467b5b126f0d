"""The trainer node learns exactly what the in-process trainer learns from the same rollouts.

A chunk of experience is collected in this process with the in-process trainer's machinery
(its worlds and actor); the reference is the in-process learner's update on that chunk. A trainer node in
its own process receives the same chunk as a Rollout message and must broadcast weights equal
to the reference, parameter for parameter, with increasing versions, and checkpoint them.
"""

from __future__ import annotations

import copy
import dataclasses
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
from formic_agent.inputs import N_EXTRA_INPUTS  # noqa: E402
from formic_ros.convert_learning import decode_rollout, encode_rollout  # noqa: E402
from formic_ros.drivers.host_actor import apply_weights  # noqa: E402
from formic_ros.drivers.trainer import TrainerNode  # noqa: E402
from formic_topics import EXTRA_INPUT_COUNT  # noqa: E402
from formic_trainer.actor import Actor  # noqa: E402
from formic_trainer.config import make_config  # noqa: E402
from formic_trainer.learner import Learner  # noqa: E402
from formic_trainer.rollout import Rollout  # noqa: E402
from formic_trainer.worlds import MetaAgents  # noqa: E402
from ros_helpers import fresh_domain_id  # noqa: E402

pytestmark = pytest.mark.filterwarnings("ignore::UserWarning", "ignore:module 'sre_:DeprecationWarning")

ROOT = Path(__file__).resolve().parents[1]
DOMAIN_ID = fresh_domain_id()
STEPS = 8
UPDATE_FIELDS = {"epochs": 2, "minibatches": 2, "rollout_steps": STEPS, "episode_steps": STEPS}
CFG = make_config("cpu", teams=(4,), world_sizes=((16, 16),), **UPDATE_FIELDS)


def quiet(_text: str) -> None:
    pass


def collect(net, episode: int) -> Rollout:
    """One chunk (a whole episode) from the training worlds and the actor, as ``formic train``
    collects it."""
    envs = MetaAgents(CFG)
    envs.reset(episode)
    actor = Actor(CFG, net, np.arange(envs.n_agents))
    actor.start_episode(episode)
    frame = envs.observe()
    for _ in range(STEPS):
        envs.step(actor.act(frame))
        frame = envs.observe()
        actor.reward(frame.rewards)
    return actor.rollout(frame, done=True, food=1.5)


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


def test_rollout_message_carries_the_rollout_field_for_field(experience):
    rollout = experience["chunks"][0]
    msg = encode_rollout(rollout)
    assert (msg.n_steps, msg.n_agents, msg.channels, msg.size) == (STEPS, 4, 8, 11)
    got = decode_rollout(msg)
    for field in dataclasses.fields(Rollout):
        want, have = getattr(rollout, field.name), getattr(got, field.name)
        assert type(have) is type(want), field.name
        if isinstance(want, np.ndarray):
            assert have.dtype == want.dtype and np.array_equal(have, want), field.name
        else:
            assert have == want, field.name
    assert EXTRA_INPUT_COUNT == N_EXTRA_INPUTS  # formic_topics restates it without torch
    msg.rewards = msg.rewards[:-1]
    with pytest.raises(ValueError, match="Rollout.rewards"):
        decode_rollout(msg)


def test_trainer_node_learns_as_the_learner_and_drops_stale_or_malformed_rollouts(experience, tmp_path):
    """In process: the node's update equals the reference and ends the rollout's episode; a
    rollout of weights it may no longer learn from, and one that does not decode, are dropped."""
    import rclpy

    first, second = (encode_rollout(rollout) for rollout in experience["chunks"])
    rclpy.init(domain_id=DOMAIN_ID)
    try:
        node = TrainerNode(Learner(CFG, tmp_path / "run", resume=False, log=quiet), max_lag=0)
        node.on_rollout(first)
        assert (node.learner.version, node.learner.episode) == (1, 1)
        assert_same_weights(snapshot(node.learner.net), experience["versions"][1])
        node.on_rollout(second)  # acted with version 0, the node is at 1
        second.rewards = second.rewards[:-1]
        node.on_rollout(second)
        assert (node.received, node.updates, node.dropped, node.learner.version) == (3, 1, 2, 1)
        newer = encode_rollout(experience["chunks"][0])
        newer.weights_version = 5  # a trainer before a restart made it: never learned from
        node.on_rollout(newer)
        assert (node.received, node.updates, node.dropped, node.learner.version) == (4, 1, 3, 1)
        node.learner.close()
        node.destroy_node()
    finally:
        rclpy.shutdown()


def test_a_rollback_of_the_fall_guard_reaches_the_hosts_with_the_next_weights(experience, tmp_path):
    """The second episode's food falls below half the first's: the guard rolls back to the
    first update's weights (best.pt), and version 2 goes out as those weights, not as the
    update it discarded (hosts would act a whole rollout on weights the learner no longer has)."""
    import rclpy

    first, second = (dataclasses.replace(rollout, food=food) for rollout, food in zip(experience["chunks"], (2.0, 0.5)))
    cfg = dataclasses.replace(CFG, guard_drop=0.5, guard_window=1)
    rclpy.init(domain_id=DOMAIN_ID)
    try:
        node = TrainerNode(Learner(cfg, tmp_path / "run", resume=False, log=quiet), max_lag=1)
        published = []
        publish = node.weights_pub.publish
        node.weights_pub.publish = lambda msg: (published.append(msg), publish(msg))
        node.learn_from(first, 0)
        node.learn_from(second, 1)
        assert [msg.version for msg in published] == [1, 2] and node.learner.guard.events == 1
        for msg in published:  # version 1: the first update; version 2: rolled back to it
            assert_same_weights(read_checkpoint(bytes(msg.data))["state_dict"], experience["versions"][1])
        node.learner.close()
        node.destroy_node()
    finally:
        rclpy.shutdown()


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
            rollouts.publish(encode_rollout(rollout))
            wait_for(lambda v=version: v in received, 30)
        out, err = node_proc.communicate(timeout=30)
        node.destroy_node()
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
    from formic_agent.inputs import NETWORK_PRESETS
    from formic_agent.network import ForMICNet

    return state_dict_bytes(ForMICNet(NETWORK_PRESETS["cpu-nest"]))


def test_trainer_and_host_name_the_peer_they_wait_for(tmp_path, monkeypatch):
    """A host waiting for weights names the trainer (or that none publishes them); a trainer that
    hears no rollout for SILENCE_S names the hosts that publish rollouts (issue: a rollout lost
    between machines showed only as the world's "check discovery" after 60 s)."""
    import rclpy
    from rclpy.executors import SingleThreadedExecutor

    from formic_ros.drivers import trainer as trainer_node
    from formic_ros.drivers.learning_host import LearningHost
    from formic_ros.graph import publishers_of

    # A domain of its own: the graph must hold exactly this test's nodes, and a participant of an
    # earlier test in this process (the "/formic/host" above) can outlive its context for a while.
    rclpy.init(domain_id=fresh_domain_id())
    executor = SingleThreadedExecutor()
    try:
        host = LearningHost([0, 1, 2, 3], CFG, name="agent_host_9")
        executor.add_node(host)
        assert "no trainer publishes on /formic/weights" in host.weights_wait_report()
        node = TrainerNode(Learner(CFG, tmp_path / "run", resume=False, log=quiet))
        executor.add_node(node)
        deadline = time.monotonic() + 20
        while time.monotonic() < deadline and not (publishers_of(host, "/formic/weights")
                                                   and publishers_of(node, "/formic/rollouts")):
            executor.spin_once(timeout_sec=0.1)
        host.newest = None  # as if the weights were lost on the way
        assert "for weights newer than version -1 from /formic/trainer: none has arrived" in host.weights_wait_report()
        said = []
        logger = type("Logger", (), {"warning": lambda _self, text: said.append(text)})()
        monkeypatch.setattr(node, "get_logger", lambda: logger)
        node.report_silence()
        assert said == []  # not yet
        node.heard_at -= trainer_node.SILENCE_S + 1
        node.report_silence()
        node.report_silence()  # once; again only after twice as long
        assert len(said) == 1 and said[0].startswith("no rollout for 11 s from /formic/agent_host_9 "
                                                     "(publishing on /formic/rollouts)"), said
        node.learner.close()
    finally:
        executor.shutdown()
        rclpy.shutdown()
