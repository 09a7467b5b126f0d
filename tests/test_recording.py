"""Recording and replay: a real recorder process records a real publisher process; third-party
readers read the result; a recorder killed with SIGKILL leaves a file that streams and repairs;
replay verifies a good recording bit for bit and rejects a tampered one; render and republish.

One ROS session (module fixture) feeds two recorders at once: one stopped with SIGINT, one
killed with SIGKILL while the publisher is still stepping.
"""

from __future__ import annotations

import hashlib
import json
import os
import select
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

pytest.importorskip("rclpy")
pytest.importorskip("formic_interfaces.msg")

from formic_record.bag import BagWriter  # noqa: E402
from formic_record.reading import KEPT_SUFFIX, Recording, repair_recording  # noqa: E402
from formic_record.replay import read_episodes, render_recording, resimulate  # noqa: E402
from formic_record.verify import verify_recording  # noqa: E402
from ros_helpers import fresh_domain_id  # noqa: E402

pytestmark = pytest.mark.filterwarnings("ignore:module 'sre_:DeprecationWarning")

ROOT = Path(__file__).resolve().parents[1]
PYTHON = sys.executable
STEPS = 120
DISCOVERED_TOPIC = "/formic/agent_0/action"  # not a world topic: the recorder must find it in the graph
DOMAIN_ID = fresh_domain_id()

# A stand-in for the world node: a real World episode on the conventional topics.
PUBLISHER = r'''
import json, sys, time
import numpy as np
import rclpy
from rclpy.node import Node
from formic_interfaces.msg import (ActionBatch, AgentAction, AgentObservation, ObservationBatch,
                                   ScenarioDescription, WorldState)
from std_msgs.msg import Float64
from formic_agent.policy import AgentBatch
from formic_ros import convert, qos
from formic_ros.world import viewer_msgs
import formic_topics as topics
from formic_world import World, WorldConfig, generate_scenario
from formic_world.metric_frame import MetricFrame

steps, rate_hz, recorders = int(sys.argv[1]), float(sys.argv[2]), int(sys.argv[3])
N = 4
rclpy.init()
node = Node("world", namespace="/formic")
types = {"scenario": ScenarioDescription, "state": WorldState, "applied_actions": ActionBatch, "score": Float64,
         "clock": viewer_msgs.Clock, "agent_action": AgentAction, "observations": ObservationBatch,
         "map": viewer_msgs.OccupancyGrid, "agent_markers": viewer_msgs.MarkerArray}
names = {"agent_action": "agent_0/action", "clock": "/clock"}
leaf = {"agent_action": topics.AGENT_ACTION}
pubs = {k: node.create_publisher(t, names.get(k, k), qos.TOPICS[leaf.get(k, names.get(k, k))].qos) for k, t in types.items()}
for a in range(N):
    pubs[f"agent_{a}/observation"] = node.create_publisher(AgentObservation, f"agent_{a}/observation", qos.STREAM)
scenario = generate_scenario(WorldConfig(height=16, width=16, n_agents=N, episode_steps=steps), 3)
world = World(scenario)
deadline = time.monotonic() + 20
while any(p.get_subscription_count() < recorders for p in pubs.values()) and time.monotonic() < deadline:
    time.sleep(0.02)

counts = dict.fromkeys(pubs, 0)
def publish(name, msg):
    pubs[name].publish(msg); counts[name] += 1

def observations(result):
    batch = AgentBatch.from_world(world, observations=result.observations, action_mask=result.action_mask)
    publish("observations", convert.encode_observation_batch(
        batch, result.rewards, result.done, train_masks=world.training_action_mask(result.action_mask)))
    for a, msg in enumerate(convert.encode_agent_observations(batch, result.rewards, result.done)):
        publish(f"agent_{a}/observation", msg)

def state():
    publish("state", convert.encode_state(world, np.zeros(N, dtype=np.int64)))
    publish("clock", viewer_msgs.clock(world.t, 0.1))
    if world.t % 10 == 0 or world.done:
        stamp = viewer_msgs.sim_time(world.t, 0.1)
        publish("score", Float64(data=world.score))
        frame = MetricFrame(*world.grid.shape)
        publish("map", viewer_msgs.occupancy_grid(world, stamp, frame))
        publish("agent_markers", viewer_msgs.agent_markers(world, stamp, frame))

publish("scenario", convert.encode_scenario(scenario, "random:0-3"))
result = world.last_result
state()
rng = np.random.default_rng(7)
print("stepping", flush=True)
for t in range(steps):
    observations(result)
    mask = world.action_mask()
    actions = np.array([rng.choice(np.flatnonzero(m)) if m.any() else 4 for m in mask])
    if t % 5 == 0:
        actions[1] = -1  # agent 1's action "did not arrive": NO_ACTION, 255 on the wire
    result = world.step(actions)
    publish("agent_action", AgentAction(step=t, agent_id=0, action=int(actions[0])))
    publish("applied_actions", convert.encode_applied(t, actions))
    state()
    if t == steps // 2:
        print("half", flush=True)
    time.sleep(1 / rate_hz)
observations(result)
time.sleep(1.0)  # delivery to the live recorder (acks would wait for the killed one too)
print(json.dumps({"counts": counts, "digest": world.state_digest(), "scenario": scenario.to_json()}), flush=True)
node.destroy_node()
rclpy.shutdown()
'''


def ros_env() -> dict[str, str]:
    env = dict(os.environ, ROS_DOMAIN_ID=str(DOMAIN_ID), FASTDDS_BUILTIN_TRANSPORTS="UDPv4",
               ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST", PYTHONUNBUFFERED="1")
    return env


def spawn(args: list[str], **kw) -> subprocess.Popen:
    return subprocess.Popen(args, env=ros_env(), cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                            text=True, start_new_session=True, **kw)


def reap(proc: subprocess.Popen, timeout: float) -> tuple[str, str]:
    """Wait for a process (SIGKILL after ``timeout``); returns its output."""
    try:
        return proc.communicate(timeout=timeout)
    except subprocess.TimeoutExpired:
        os.killpg(proc.pid, signal.SIGKILL)
        return proc.communicate()


def formic(*args: str, timeout: float = 60) -> subprocess.CompletedProcess:
    return subprocess.run([PYTHON, "-m", "formic_cli.main", *args], env=ros_env(), cwd=ROOT,
                          capture_output=True, text=True, timeout=timeout)


def digest_of(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


@pytest.fixture(scope="module")
def session(tmp_path_factory):
    """Two recorders (one to be stopped, one to be killed) record one publisher's episode."""
    tmp = tmp_path_factory.mktemp("recording")
    good, killed = tmp / "good", tmp / "killed"
    script = tmp / "publisher.py"
    script.write_text(PUBLISHER)
    recorder = [PYTHON, "-m", "formic_cli.main", "record", "--chunk-kb", "16", "--json", "--out"]
    procs = [spawn(recorder + [str(good)]), spawn(recorder + [str(killed)])]
    publisher = spawn([PYTHON, str(script), str(STEPS), "100", "2"])
    try:
        ready, _, _ = select.select([publisher.stdout], [], [], 40)
        assert ready and publisher.stdout.readline().strip() == "stepping", reap(publisher, 5)
        ready, _, _ = select.select([publisher.stdout], [], [], 40)
        assert ready and publisher.stdout.readline().strip() == "half", reap(publisher, 5)
        time.sleep(0.6)  # a flush (every 0.5 s) of what the recorder has by then
        os.killpg(procs[1].pid, signal.SIGKILL)  # mid-episode
        reap(procs[1], 5)
        out, err = reap(publisher, 30)
        assert publisher.returncode == 0, err
        published = json.loads(out.strip().splitlines()[-1])
        time.sleep(0.3)
        procs[0].send_signal(signal.SIGINT)
        rec_out, rec_err = reap(procs[0], 15)
        assert procs[0].returncode == 0, rec_err
    finally:
        for proc in (*procs, publisher):
            if proc.poll() is None:
                os.killpg(proc.pid, signal.SIGKILL)
                proc.communicate()
    return {"good": good, "killed": killed, "published": published, "recorder": json.loads(rec_out), "tmp": tmp}


def test_recorder_writes_a_complete_rosbag2_recording(session):
    good, published = session["good"], session["published"]
    assert (good / "metadata.yaml").is_file() and (good / "good.mcap").is_file()
    recording = Recording(good)
    assert recording.complete, recording.describe()
    expected = {f"/formic/{k}": v for k, v in published["counts"].items() if k not in ("clock", "agent_action")}
    expected |= {"/clock": published["counts"]["clock"], DISCOVERED_TOPIC: published["counts"]["agent_action"]}
    got = {t: i.count for t, i in recording.topics.items() if t in expected}
    assert got == expected
    assert session["recorder"]["topics"] == {t: c for t, c in expected.items()}
    info = recording.run_info
    assert info["seed"] == "3" and info["policies"] == "random:0-3"
    assert info["scenario"] == published["scenario"]
    assert json.loads(info["scenario"])["seed"] == 3 and len(info["config_digest"]) == 16
    assert info["package_version"]


def test_third_party_readers_decode_the_recording(session):
    """mcap_ros2 (in a process that never imports rclpy) and rosbags read every message."""
    good, published = session["good"], session["published"]
    script = (
        "import json, sys\n"
        "from mcap.reader import make_reader\n"
        "from mcap_ros2.decoder import DecoderFactory\n"
        "counts, last = {}, None\n"
        f"with open({str(good / 'good.mcap')!r}, 'rb') as f:\n"
        "    reader = make_reader(f, decoder_factories=[DecoderFactory()])\n"
        "    assert reader.get_header().profile == 'ros2'\n"
        "    for schema, channel, message, decoded in reader.iter_decoded_messages():\n"
        "        assert schema.encoding == 'ros2msg' and channel.message_encoding == 'cdr'\n"
        "        counts[channel.topic] = counts.get(channel.topic, 0) + 1\n"
        "        if channel.topic == '/formic/state':\n"
        "            last = decoded.state_digest\n"
        "assert 'rclpy' not in sys.modules\n"
        "print(json.dumps({'counts': counts, 'last': last}))\n"
    )
    done = subprocess.run([PYTHON, "-c", script], capture_output=True, text=True, timeout=60)
    assert done.returncode == 0, done.stderr
    result = json.loads(done.stdout)
    assert result["counts"]["/formic/state"] == published["counts"]["state"]
    assert result["last"] == published["digest"]

    from rosbags.rosbag2 import Reader
    from rosbags.typesys import Stores, get_types_from_msg, get_typestore

    store = get_typestore(Stores.EMPTY)
    with Reader(good) as reader:
        for conn in reader.connections:
            store.register(get_types_from_msg(conn.msgdef.data, conn.msgtype))
        states = [store.deserialize_cdr(raw, conn.msgtype) for conn, _, raw in reader.messages()
                  if conn.topic == "/formic/state"]
        assert reader.message_count == sum(published["counts"].values())
    assert states[-1].state_digest == published["digest"]
    assert states[0].step == 0 and states[-1].step == STEPS


def test_killed_recorder_leaves_a_streamable_file_that_repairs(session):
    killed = session["killed"]
    mcap = killed / "killed.mcap"
    assert not (killed / "metadata.yaml").exists()
    recording = Recording(killed)
    assert recording.streamed and "no usable summary" in recording.problem
    states = recording.topics["/formic/state"].count
    assert 5 < states < STEPS + 1, recording.describe()
    assert recording.run_info["seed"] == "3"  # the run description survives the kill
    before = digest_of(mcap)
    done = formic("replay", str(killed), "--repair", "--json")
    assert done.returncode == 0, done.stderr
    assert json.loads(done.stdout)["repaired"] is True
    kept = killed / ("killed.mcap" + KEPT_SUFFIX)
    assert digest_of(kept) == before  # the original bytes are kept
    repaired = Recording(killed)
    assert repaired.complete, repaired.describe()
    assert repaired.topics["/formic/state"].count == states
    assert repaired.run_info["seed"] == "3"
    from rosbags.rosbag2 import Reader

    with Reader(killed) as reader:
        assert reader.message_count == recording.message_count
    report = verify_recording(killed)
    assert report.ok and report.states_checked >= states - 1, report.summary()
    assert not repair_recording(killed).repaired  # a second repair has nothing to do


def test_replay_verify_accepts_the_recording(session):
    done = formic("replay", str(session["good"]), "--verify")
    assert done.returncode == 0, done.stdout + done.stderr
    assert done.stdout.startswith("OK") and f"{STEPS + 1} recorded states" in done.stdout
    published = session["published"]["counts"]
    assert f"{sum(published.values()) - published['scenario'] - published['agent_action'] - published['applied_actions']}"\
        " recorded messages on" in done.stdout


def _tampered_copy(source: Path, target: Path, change, keep=lambda topic, msg, index: True,
                   summary: str | None = None) -> None:
    """Rewrite a recording with ``change(topic, decoded, index)`` applied to its messages, only
    those ``keep(topic, decoded, index)`` accepts, and a world summary ``summary`` (JSON) at the end."""
    recording = Recording(source)
    store = recording.typestore()
    with BagWriter(target) as writer:
        for topic, info in recording.topics.items():
            writer.add_topic(topic, info.msgtype, info.qos)
        seen: dict[str, int] = {}
        for m in recording.messages():
            index = seen[m.topic] = seen.get(m.topic, -1) + 1
            msg = store.deserialize_cdr(m.data, m.msgtype)
            data = m.data
            if change(m.topic, msg, index):
                data = bytes(store.serialize_cdr(msg, m.msgtype))
            if keep(m.topic, msg, index):
                writer.write(m.topic, m.log_time, data)
        if summary is not None:
            string = writer.typestore.types["std_msgs/msg/String"]
            writer.add_topic("/formic/summary", "std_msgs/msg/String")
            writer.write("/formic/summary", m.log_time + 1,
                         writer.typestore.serialize_cdr(string(summary), string.__msgtype__))
        writer.set_run_info(recording.run_info)


def test_replay_verify_detects_a_tampered_action(session):
    episode = read_episodes(Recording(session["good"]))[0]
    # an agent that was free and moved at step t: withholding its action changes the state
    worlds = resimulate(episode)
    first = next(worlds)
    pos, queued, moves = first.pos.copy(), first.queued.copy(), []
    for world in worlds:
        moves += [(world.t - 1, a) for a in (0, 2, 3) if not queued[a] and tuple(pos[a]) != tuple(world.pos[a])]
        pos, queued = world.pos.copy(), world.queued.copy()
    step, agent = moves[len(moves) // 2]

    def change(topic, msg, index):
        if topic == "/formic/applied_actions" and msg.step == step:
            msg.actions = msg.actions.copy()
            msg.actions[agent] = 255
            return True
        return False

    target = session["tmp"] / "tampered-action"
    _tampered_copy(session["good"], target, change)
    done = formic("replay", str(target), "--verify")
    assert done.returncode == 1
    assert done.stdout.startswith("FAILED") and f"mismatch at step {step + 1}" in done.stdout


def _bump_score(state_index: int):
    """A change for ``_tampered_copy``: the ``state_index``-th state's score is off by one."""
    def change(topic, msg, index):
        if topic == "/formic/state" and index == state_index:
            msg.score += 1.0
            return True
        return False
    return change


def test_replay_verify_detects_a_tampered_state(session):
    target = session["tmp"] / "tampered-state"
    _tampered_copy(session["good"], target, _bump_score(40))
    report = verify_recording(target)
    assert not report.ok and "mismatch at step 40: score" in report.summary()


def _no_change(topic, msg, index) -> bool:
    return False


def _stopped_copy(session, name: str, step: int, change=_no_change, summary: str | None = None) -> Path:
    """The good recording as a recorder stopped during step ``step`` leaves it (each topic has
    its own reader): the state and clock of step ``step + 1`` are in, the actions applied at
    ``step`` are not (still queued), nor is anything later."""
    def keep(topic, msg, index):
        if topic in ("/formic/applied_actions", DISCOVERED_TOPIC):
            return msg.step < step
        if topic == "/formic/state":
            return msg.step <= step + 1
        if topic == "/clock":
            return msg.clock.sec * 10 + msg.clock.nanosec // 100_000_000 <= step + 1
        if topic in ("/formic/map", "/formic/agent_markers"):
            stamp = msg.header.stamp if topic == "/formic/map" else msg.markers[0].header.stamp
            return stamp.sec * 10 + stamp.nanosec // 100_000_000 <= step
        if topic == "/formic/score":
            return index <= step // 10  # one with each map, every 10 steps
        return getattr(msg, "step", 0) <= step

    target = session["tmp"] / name
    _tampered_copy(session["good"], target, change, keep, summary)
    return target


@pytest.mark.parametrize("step", [0, 37, STEPS - 1])
def test_a_recording_stopped_mid_step_verifies_up_to_its_last_complete_step(session, step):
    report = verify_recording(_stopped_copy(session, f"stopped-{step}", step))
    assert report.ok and report.interrupted_at == step, report.summary()
    assert report.states_checked == step + 1 and not report.mismatches
    assert (f"recording ends at step {step} of {STEPS} (interrupted); 2 recorded message(s) of step {step + 1} "
            "after it not checked") in report.summary()


def test_replay_verify_says_where_an_interrupted_recording_ends(session):
    done = formic("replay", str(_stopped_copy(session, "stopped-cli", 50)), "--verify")
    assert done.returncode == 0 and done.stdout.startswith("OK"), done.stdout + done.stderr
    assert f"recording ends at step 50 of {STEPS} (interrupted)" in done.stdout


def test_a_stopped_recording_still_fails_a_mismatch_before_the_stop(session):
    report = verify_recording(_stopped_copy(session, "stopped-tampered", 60, _bump_score(10)))
    assert not report.ok and "/formic/state: mismatch at step 10: score" in report.summary()


def test_a_recording_that_lost_applied_actions_fails(session):
    """Not an interruption: a step's applied actions missing before recorded ones, or the last
    ones missing although the world's summary says it played the episode to its end."""
    gap = session["tmp"] / "gap"
    _tampered_copy(session["good"], gap, _no_change,
                   keep=lambda topic, msg, index: not (topic == "/formic/applied_actions" and msg.step == 50))
    report = verify_recording(gap)
    assert not report.ok and report.interrupted_at is None
    assert f"no applied actions for step 50 but for {STEPS - 51} later step(s) from step 51" in report.summary()
    finished = _stopped_copy(session, "stopped-finished", 60, summary=json.dumps({"seed": 3, "steps": STEPS}))
    report = verify_recording(finished)
    assert not report.ok and "but the world finished the episode" in report.summary(), report.summary()


def _index_record_offset(mcap: Path, kind: str) -> int:
    """Where a message index record (the second chunk's first) or the first chunk index record
    (in the summary section) starts."""
    from mcap.reader import make_reader

    with mcap.open("rb") as handle:
        summary = make_reader(handle).get_summary()
    if kind == "message index":
        chunk = sorted(summary.chunk_indexes, key=lambda c: c.chunk_start_offset)[1]
        return min(chunk.message_index_offsets.values())
    data = mcap.read_bytes()
    at = int.from_bytes(data[-8 - 29 + 9:-8 - 29 + 17], "little")  # the footer's summary start
    while data[at] != 0x08:  # chunk index opcode
        at += 9 + int.from_bytes(data[at + 1:at + 9], "little")
    return at


@pytest.mark.parametrize("kind", ["message index", "chunk index"])
def test_repair_keeps_every_chunk_when_an_index_record_is_damaged(session, kind):
    import shutil

    target = session["tmp"] / f"damaged-{kind.replace(' ', '-')}"
    shutil.copytree(session["good"], target)
    counts = {t: i.count for t, i in Recording(target).topics.items()}
    mcap = target / "good.mcap"
    data = bytearray(mcap.read_bytes())
    data[_index_record_offset(mcap, kind) + 2] ^= 0x40  # its length: the records after it no longer line up
    mcap.write_bytes(bytes(data))
    assert Recording(target).corruption() is not None
    done = formic("replay", str(target), "--repair", "--json")
    assert done.returncode == 0, done.stdout + done.stderr
    result = json.loads(done.stdout)
    assert result["corrupted"] and result["messages"] == sum(counts.values()) and result["dropped"] == 0, result
    repaired = Recording(target)
    assert {t: i.count for t, i in repaired.topics.items()} == counts
    report = verify_recording(target)
    assert report.ok and not report.mismatches and report.states_checked == STEPS + 1, report.summary()


def test_render_recording_writes_a_gif(session):
    from PIL import Image

    out = session["tmp"] / "episode.gif"
    frames = render_recording(session["good"], out, scale=2, fps=20)
    assert frames == STEPS + 1
    with Image.open(out) as gif:
        assert gif.n_frames > 1 and gif.size == (32, 32 + 14)


def test_republish_plays_the_topics_back(session, monkeypatch):
    """`formic replay --republish` publishes the recorded CDR; a subscriber decodes it."""
    import rclpy
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.qos import QoSProfile, ReliabilityPolicy

    from formic_interfaces.msg import ScenarioDescription, WorldState
    from formic_ros.recording.recorder import subscription_qos

    for key in ("ROS_DOMAIN_ID", "FASTDDS_BUILTIN_TRANSPORTS", "ROS_AUTOMATIC_DISCOVERY_RANGE"):
        monkeypatch.setenv(key, ros_env()[key])
    context = rclpy.Context()
    rclpy.init(context=context, domain_id=DOMAIN_ID)
    try:
        node = rclpy.create_node("probe", context=context)
        executor = SingleThreadedExecutor(context=context)
        executor.add_node(node)
        digests, scenarios = [], []
        node.create_subscription(WorldState, "/formic/state", lambda m: digests.append(m.state_digest),
                                 QoSProfile(depth=200, reliability=ReliabilityPolicy.RELIABLE))
        node.create_subscription(ScenarioDescription, "/formic/scenario", scenarios.append, subscription_qos(True))
        player = spawn([PYTHON, "-m", "formic_cli.main", "replay", str(session["good"]), "--republish",
                        "--rate", "0", "--wait", "30", "--topics", "/formic/state,/formic/scenario"])
        deadline = time.monotonic() + 40
        while len(digests) < STEPS + 1 and time.monotonic() < deadline and player.poll() is None:
            executor.spin_once(timeout_sec=0.1)
        for _ in range(20):  # what was sent before the player exited
            executor.spin_once(timeout_sec=0.05)
        out, err = reap(player, 15)
        assert player.returncode == 0, err
    finally:
        rclpy.shutdown(context=context)
    assert len(digests) == STEPS + 1 and digests[-1] == session["published"]["digest"]
    assert scenarios and scenarios[0].seed == 3
    assert "republished" in out


def test_foxglove_layout_shows_map_markers_and_score():
    layout = json.loads((ROOT / "foxglove" / "formic_layout.json").read_text())
    text = json.dumps(layout["configById"])
    for topic in ("/formic/map", "/formic/agent_markers", "/formic/score"):
        assert topic in text
    kinds = {key.split("!")[0] for key in layout["configById"]}
    assert {"3D", "Plot"} <= kinds


def test_recording_io_imports_no_rclpy():
    code = "import sys, formic_record.bag, formic_record.replay; print(any(m.startswith('rclpy') for m in sys.modules))"
    out = subprocess.run([PYTHON, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "False"


def _flip(values, index: int, dtype):
    """A copy of an array field with one byte of element ``index`` flipped."""
    import numpy as np

    out = np.array(values, dtype=dtype)
    out.view(np.uint8)[index * out.itemsize] ^= 0x01
    return out


@pytest.mark.parametrize("topic, field", [
    ("/formic/agent_2/observation", "data"), ("/formic/observations", "loads"), ("/formic/state", "grid"),
    ("/formic/state", "pheromone"), ("/clock", "clock"), ("/formic/map", "data"), ("/formic/score", "data"),
])
def test_replay_verify_detects_one_changed_byte(session, topic, field):
    import numpy as np

    def change(name, msg, index):
        if name != topic or index != 3:
            return False
        if field == "clock":
            msg.clock.nanosec ^= 1
        elif field == "data" and topic == "/formic/score":
            msg.data = float(_flip([msg.data], 0, np.float64)[0])
        else:
            values = getattr(msg, field)
            position = int(np.flatnonzero(np.asarray(values))[0]) if np.asarray(values).any() else 0
            setattr(msg, field, _flip(values, position, np.asarray(values).dtype))
        return True

    target = session["tmp"] / f"flipped-{topic.strip('/').replace('/', '-')}-{field}"
    _tampered_copy(session["good"], target, change)
    report = verify_recording(target)
    assert not report.ok and topic in report.mismatches, report.summary()
    assert report.mismatches[topic]["count"] >= 1
    done = formic("replay", str(target), "--verify")
    assert done.returncode == 1 and topic in done.stdout and "Traceback" not in done.stderr


def _corrupt_offsets(mcap: Path) -> dict[str, int]:
    from mcap.reader import make_reader

    with mcap.open("rb") as handle:
        summary = make_reader(handle).get_summary()
    chunk = sorted(summary.chunk_indexes, key=lambda c: c.chunk_start_offset)[1]
    size = mcap.stat().st_size
    footer_start = size - 8 - 29
    with mcap.open("rb") as handle:
        handle.seek(footer_start + 9)
        summary_start = int.from_bytes(handle.read(8), "little")
    return {"header": 22, "chunk": chunk.chunk_start_offset + 53 + chunk.compressed_size // 2,
            "summary": summary_start + 12, "footer": size - 8 - 2}


@pytest.mark.parametrize("where", ["header", "chunk", "summary", "footer"])
def test_a_flipped_file_byte_is_a_clean_error(session, where):
    import shutil

    results = {}
    for mode in ("--verify", "--repair"):
        target = session["tmp"] / f"corrupt-{where}{mode}"
        shutil.copytree(session["good"], target)
        mcap = target / "good.mcap"
        data = bytearray(mcap.read_bytes())
        data[_corrupt_offsets(mcap)[where]] ^= 0x40
        mcap.write_bytes(bytes(data))
        results[mode] = done = formic("replay", str(target), mode)
        assert "Traceback" not in done.stderr, done.stderr
    verify, repair = results["--verify"], results["--repair"]
    assert verify.returncode != 0 and "corrupted" in verify.stderr, verify.stdout + verify.stderr
    assert len(verify.stderr.strip().splitlines()) == 1, verify.stderr
    assert "nothing to repair" not in repair.stdout
    assert "corrupted" in repair.stdout + repair.stderr, repair.stdout + repair.stderr
    if repair.returncode == 0:  # rebuilt: what it kept verifies, and a lost chunk shifts no /clock
        assert "dropped" in repair.stdout
        kept = session["tmp"] / f"corrupt-{where}--repair"
        assert Recording(kept).corruption() is None
        report = verify_recording(kept)
        assert report.ok and not report.mismatches, report.summary()


@pytest.mark.parametrize("signals", [(signal.SIGINT, signal.SIGINT), (signal.SIGHUP,), (signal.SIGTERM, signal.SIGHUP)])
def test_recorder_closes_the_recording_on_repeated_signals_and_sighup(tmp_path, signals):
    out = tmp_path / "rec"
    proc = spawn([PYTHON, "-m", "formic_cli.main", "record", "--out", str(out)])
    try:
        ready, _, _ = select.select([proc.stderr], [], [], 60)
        assert ready and "recording to" in proc.stderr.readline(), reap(proc, 5)
        for sig in signals:
            proc.send_signal(sig)
            time.sleep(0.01)
        started = time.monotonic()
        _, err = reap(proc, 15)
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
    assert time.monotonic() - started < 10
    assert proc.returncode == 0 and "Traceback" not in err, err
    assert (out / "metadata.yaml").is_file()
    recording = Recording(out)
    assert recording.complete and recording.corruption() is None, recording.describe()


def test_run_record_holds_every_message_of_every_topic(tmp_path):
    """8 C-SAF-11 agents, per-agent transport, 30 steps: every topic the world publishes holds
    one message a step (observations: steps + 1, state and clock: steps + 1, applied: steps)."""
    steps, agents, out = 30, 8, tmp_path / "run"
    done = formic("run", "--agents", str(agents), "--size", "24", "--steps", str(steps), "--policy", "csaf11",
                  "--transport", "per-agent", "--record", str(out), "--json", "--timeout", "150", timeout=200)
    assert done.returncode == 0, done.stderr[-3000:]
    recording = Recording(out)
    store, stepped = recording.typestore(), {}
    for m in recording.messages():
        step = getattr(store.deserialize_cdr(m.data, m.msgtype), "step", None) if m.msgtype.startswith("formic_interfaces") else None
        stepped.setdefault(m.topic, set()).add(step if step is not None else len(stepped.get(m.topic, ())))
    everything, applied = set(range(steps + 1)), set(range(steps))  # resent observations count once
    expected = {"/formic/state": everything, "/clock": everything, "/formic/applied_actions": applied}
    expected |= {f"/formic/agent_{a}/observation": everything for a in range(agents)}
    expected |= {f"/formic/agent_{a}/action": applied for a in range(agents)}
    assert {t: sorted(stepped.get(t, ())) for t in expected} == {t: sorted(v) for t, v in expected.items()}
    assert verify_recording(out).ok


@pytest.mark.parametrize("signals", [(signal.SIGHUP,), (signal.SIGINT,) * 3], ids=["sighup", "three-sigint"])
def test_an_interrupted_run_closes_its_recording_and_it_verifies(tmp_path, signals):
    """A closing terminal's SIGHUP, or Ctrl-C pressed three times, mid-episode: every process
    stops, the recording is closed (metadata.yaml, an index) and verifies up to where it ends."""
    from ros_helpers import Spawner, descendants, fresh_domain_id, running

    spawner, out = Spawner(tmp_path, fresh_domain_id()), tmp_path / "run"
    try:
        run = spawner.formic("run", "run", "--agents", "4", "--size", "16", "--steps", "100000", "--policy", "csaf11",
                             "--record", str(out), "--domain-id", str(spawner.domain_id), limit_s=150)
        run.wait_for_text("stepping:", timeout=90)
        time.sleep(0.5)  # some steps into the episode
        family = descendants(run.pid)
        for sig in signals:
            run.popen.send_signal(sig)
            time.sleep(0.01)
        assert run.wait(timeout=60) == 130, run.output()[-3000:]
        assert [pid for pid in family if running(pid)] == [], "orphans"
    finally:
        spawner.reap_all()
    assert (out / "metadata.yaml").is_file() and Recording(out).complete, run.output()[-3000:]
    done = formic("replay", str(out), "--verify")
    assert done.returncode == 0 and "(interrupted)" in done.stdout, done.stdout + done.stderr


def test_a_stopped_recorder_records_what_already_arrived_before_it_closes(tmp_path):
    """Stopped at once (``duration_s=0``: its loop never spins), the recorder still takes the
    messages that reached it before the stop: a launcher stops it right after the world leaves,
    when a busy machine may not have let it read the last steps yet."""
    from ros_helpers import fresh_domain_id
    from std_msgs.msg import String

    import formic_topics as topics
    from formic_ros.qos import reliable
    from formic_ros.recording.recorder import RecorderOptions, record

    sent, name = 50, topics.full_name(topics.DEFAULT_NAMESPACE, topics.SUMMARY)

    def publish_burst(node) -> None:
        publisher = node.create_publisher(String, name, reliable(sent, latched=True))
        deadline = time.monotonic() + 20
        while publisher.get_subscription_count() == 0 and time.monotonic() < deadline:
            time.sleep(0.01)
        for i in range(sent):
            publisher.publish(String(data=str(i)))

    result = record(tmp_path / "rec", RecorderOptions(), domain_id=fresh_domain_id(), duration_s=0.0,
                    on_ready=publish_burst)
    assert result["topics"].get(name) == sent, result
    assert Recording(tmp_path / "rec").topics[name].count == sent
