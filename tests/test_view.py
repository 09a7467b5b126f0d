"""The live view (formic_view) seen through a real Foxglove WebSocket protocol client: connect
(subprotocol ``foxglove.sdk.v1``: foxglove-sdk's name for the unchanged
``foxglove.websocket.v1`` protocol, which it no longer accepts), read serverInfo and the advertised channels,
subscribe to every channel and decode the binary messageData frames with the advertised
schemas (protobuf FileDescriptorSets, JSON schema). First the LiveView fed directly by a
World, then the command line: ``formic sim --view`` and a real ``formic run --view``."""

from __future__ import annotations

import base64
import json
import os
import signal
import socket
import struct
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("foxglove")
websockets_sync = pytest.importorskip("websockets.sync.client")
from google.protobuf import descriptor_pb2, descriptor_pool, message_factory  # noqa: E402

from formic_view import announcement  # noqa: E402
from formic_view.live import AGENTS_TOPIC, CELL, SCORE_TOPIC, STATE_TOPIC, WORLD_TOPIC, LiveView  # noqa: E402
from formic_world import WorldConfig, World, generate_scenario  # noqa: E402

TOPICS = (WORLD_TOPIC, AGENTS_TOPIC, SCORE_TOPIC, STATE_TOPIC)  # the state goes out last of a step
SUBPROTOCOLS = ["foxglove.sdk.v1", "foxglove.websocket.v1"]  # what Foxglove offers; the server picks
MESSAGE_DATA = 1  # binary opcode of a server's messageData frame
ROOT = Path(__file__).resolve().parents[1]


class FoxgloveClient:
    """The client side of the Foxglove WebSocket protocol, as much as a viewer needs (a
    context manager: the connection closes on leaving it)."""

    def __init__(self, url: str, timeout_s: float = 20.0):
        self.url, self.timeout_s = url, timeout_s
        self.server_info: dict | None = None
        self.channels: dict[int, dict] = {}  # channel id -> advertised channel
        self.decoders: dict[int, object] = {}  # channel id -> bytes -> message
        self.subscriptions: dict[int, dict] = {}  # subscription id -> channel

    def __enter__(self) -> FoxgloveClient:
        deadline = time.monotonic() + self.timeout_s
        while True:  # the server may still be starting
            try:
                self._connection = websockets_sync.connect(self.url, subprotocols=SUBPROTOCOLS, max_size=None,
                                                           open_timeout=5)
                self.ws = self._connection.__enter__()
                break
            except OSError:
                if time.monotonic() > deadline:
                    raise
                time.sleep(0.2)
        assert self.ws.subprotocol == SUBPROTOCOLS[0]
        return self

    def __exit__(self, *exc) -> None:
        self._connection.__exit__(*exc)

    def _control(self, text: str) -> None:
        op = json.loads(text)
        if op["op"] == "serverInfo":
            self.server_info = op
        elif op["op"] == "advertise":
            for channel in op["channels"]:
                self.channels[channel["id"]] = channel
                self.decoders[channel["id"]] = decoder(channel)

    def await_channels(self, topics, timeout_s: float = 20.0) -> None:
        deadline = time.monotonic() + timeout_s
        while not set(topics) <= {c["topic"] for c in self.channels.values()}:  # every one advertised
            frame = self.ws.recv(timeout=max(0.01, deadline - time.monotonic()))
            if isinstance(frame, str):
                self._control(frame)

    def subscribe_all(self) -> None:
        subs = [{"id": i, "channelId": cid} for i, cid in enumerate(sorted(self.channels))]
        self.subscriptions = {s["id"]: self.channels[s["channelId"]] for s in subs}
        self.ws.send(json.dumps({"op": "subscribe", "subscriptions": subs}))

    def messages(self, until, timeout_s: float = 30.0):
        """Decoded (topic, timestamp ns, message) of every messageData frame until ``until(topic,
        message)`` says so (or the server closes)."""
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            try:
                frame = self.ws.recv(timeout=max(0.01, deadline - time.monotonic()))
            except TimeoutError:
                break
            except Exception as exc:  # the server went away: the run is over
                if type(exc).__name__.startswith("ConnectionClosed"):
                    return
                raise
            if isinstance(frame, str):
                self._control(frame)
                continue
            assert frame[0] == MESSAGE_DATA, f"unexpected binary opcode {frame[0]}"
            sub_id, stamp = struct.unpack_from("<IQ", frame, 1)
            channel = self.subscriptions[sub_id]
            message = self.decoders[channel["id"]](frame[13:])
            yield channel["topic"], stamp, message
            if until(channel["topic"], message):
                return
        raise TimeoutError("no end of the messages in time")


def decoder(channel: dict):
    """bytes -> message, from the channel's advertised encoding and schema only."""
    if channel["encoding"] == "protobuf":
        assert channel["schemaEncoding"] == "protobuf"
        files = descriptor_pb2.FileDescriptorSet.FromString(base64.b64decode(channel["schema"]))
        pool = descriptor_pool.DescriptorPool()
        for file in files.file:
            pool.Add(file)
        cls = message_factory.GetMessageClass(pool.FindMessageTypeByName(channel["schemaName"]))
        return cls.FromString
    assert channel["encoding"] == "json" and channel["schemaEncoding"] == "jsonschema"
    schema = json.loads(channel["schema"])
    kinds = {"number": (int, float), "integer": int, "null": type(None)}

    def decode(data: bytes) -> dict:
        message = json.loads(data)
        assert set(message) == set(schema["properties"])
        for key, value in message.items():
            allowed = schema["properties"][key]["type"]
            allowed = allowed if isinstance(allowed, list) else [allowed]
            assert isinstance(value, tuple(t for a in allowed for t in np.atleast_1d(kinds[a]))), (key, value)
        return message

    return decode


def grid_cells(grid) -> np.ndarray:
    """A foxglove.Grid's cells as (rows from the top, columns) of the CELL layout."""
    fields = {f.name: f.offset for f in grid.fields}
    assert fields == {name: CELL.fields[name][1] for name in CELL.names}
    assert grid.cell_stride == CELL.itemsize and grid.row_stride == grid.column_count * CELL.itemsize
    return np.frombuffer(grid.data, dtype=CELL).reshape(-1, grid.column_count)[::-1]


def agent_cells(scene, height: int) -> np.ndarray:
    """(row, column) of each agent entity, in agent order."""
    entities = sorted(scene.entities, key=lambda e: int(e.id.split("_")[1]))
    points = [(e.spheres or e.cubes)[0].pose.position for e in entities]
    return np.array([(height - 1 - int(p.y - 0.5), int(p.x - 0.5)) for p in points])


def small_world(n_agents: int = 12, steps: int = 40, capacity: str = "finite") -> World:
    config = WorldConfig(height=24, width=24, n_agents=n_agents, episode_steps=steps, capacity=capacity)
    return World(generate_scenario(config, 3))


def test_live_view_streams_world_agents_and_score_decoded_with_advertised_schemas():
    world = small_world()
    n, height = world.config.n_agents, world.grid.shape[0]
    rng = np.random.default_rng(0)
    expected = {}
    with LiveView(port=0, max_hz=1e6) as view:  # no rate limit: every step goes out
        with FoxgloveClient(view.url) as client:
            client.await_channels(TOPICS)
            assert client.server_info is not None and client.server_info["name"] == "formic"
            client.subscribe_all()
            assert view.wait_for_viewer(10)
            deadline = time.monotonic() + 10
            while not all(c.has_sinks() for c in (view.world_channel, view.agents_channel, view.score_channel)):
                assert time.monotonic() < deadline
                time.sleep(0.01)
            while not world.done:
                world.step(rng.integers(0, 5, n))
                expected[world.t] = dict(score=world.score, pos=world.pos.copy(), loads=world.loads.copy(),
                                         queued=world.queued.copy(), pheromone=world.visible_pheromone().copy(),
                                         grid=world.grid.copy(),
                                         food_left=world.resource_remaining.sum() / world.load_full)
                assert view.publish(world, final=world.done)
            got = {topic: {} for topic in TOPICS}
            for topic, stamp, message in client.messages(
                    until=lambda topic, message: all(len(v) == len(expected) for v in got.values())):
                step = round(stamp / 1e8)  # sim time, dt 0.1 s
                got[topic][step] = message
    assert {topic: sorted(v) for topic, v in got.items()} == {topic: sorted(expected) for topic in TOPICS}
    for step, want in expected.items():
        grid = got[WORLD_TOPIC][step]
        assert grid.frame_id == "map" and grid.column_count == 24 and grid.cell_size.x == 1.0
        cells = grid_cells(grid)
        np.testing.assert_array_equal(cells["pheromone"], want["pheromone"].astype(np.float32))
        np.testing.assert_array_equal(cells["cell"], want["grid"])
        assert (cells["alpha"] == 255).all()
        scene = got[AGENTS_TOPIC][step]
        assert len(scene.entities) == n
        np.testing.assert_array_equal(agent_cells(scene, height), want["pos"])
        entities = sorted(scene.entities, key=lambda e: int(e.id.split("_")[1]))
        assert [len(e.cubes) == 1 for e in entities] == want["queued"].tolist()  # queued: cube, free: sphere
        assert [float(e.metadata[0].value) for e in entities] == pytest.approx(want["loads"].tolist())
        assert entities[0].timestamp.seconds * 10 + round(entities[0].timestamp.nanos / 1e8) == step
        assert got[SCORE_TOPIC][step] == {"data": want["score"]}
        state = got[STATE_TOPIC][step]
        assert state["score"] == want["score"] and state["step"] == step
        assert state["food_carried"] == pytest.approx(want["loads"].sum())
        assert state["carrying"] == (want["loads"] > 0).sum() and state["queued"] == want["queued"].sum()
        assert state["agents"] == n and state["sim_time"] == pytest.approx(step * 0.1)
        assert state["food_left"] == pytest.approx(want["food_left"])
    assert any(s["score"] > 0 or s["food_carried"] > 0 for s in got[STATE_TOPIC].values())


def test_live_view_is_rate_limited_builds_nothing_unwatched_and_always_sends_the_final_step():
    world = small_world(steps=400, capacity="infinite")
    rng = np.random.default_rng(1)
    with LiveView(port=0, max_hz=5) as view:
        assert not view.publish(world)  # nobody subscribed: nothing built or sent
        with FoxgloveClient(view.url) as client:
            client.await_channels(TOPICS)
            client.subscribe_all()
            assert view.wait_for_viewer(10)
            time.sleep(0.2)  # the subscription reaches every channel
            started, sent = time.monotonic(), []
            while not world.done:
                world.step(rng.integers(0, 5, world.config.n_agents))
                if view.publish(world, final=world.done):
                    sent.append(world.t)
                time.sleep(0.002)
            elapsed = time.monotonic() - started
            steps = [round(stamp / 1e8) for topic, stamp, _ in client.messages(
                until=lambda topic, message: topic == STATE_TOPIC and message["step"] == 400) if topic == STATE_TOPIC]
    assert sent[-1] == 400 and steps == sent
    assert 2 <= len(sent) <= 5 * elapsed + 3  # about 5 a second, not 400


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _formic(args: list[str], stderr: Path, env: dict[str, str] | None = None) -> subprocess.Popen:
    env = dict(env or os.environ)
    env["PYTHONPATH"] = os.pathsep.join([str(ROOT / "src"), os.environ.get("PYTHONPATH", "")])
    with open(stderr, "w") as err:  # a file, not a pipe: the children's logs must never block them
        return subprocess.Popen([sys.executable, "-m", "formic_cli.main", *args], cwd=ROOT, env=env,
                                stdin=subprocess.DEVNULL, stdout=subprocess.PIPE, stderr=err, text=True,
                                start_new_session=True)


def _reap(process: subprocess.Popen, timeout_s: float) -> str:
    """Stdout of the process once it exits; SIGINT, then SIGKILL to its group after ``timeout_s``."""
    try:
        return process.communicate(timeout=timeout_s)[0]
    except subprocess.TimeoutExpired:
        os.killpg(process.pid, signal.SIGINT)
        try:
            return process.communicate(timeout=15)[0]
        except subprocess.TimeoutExpired:
            os.killpg(process.pid, signal.SIGKILL)
            return process.communicate()[0]


def _watch(process: subprocess.Popen, stderr: Path, port: int, last_step: int) -> dict[str, dict[int, object]]:
    """Wait for the command's announcement, connect to its live view, subscribe to every
    channel and collect the decoded messages by step until ``last_step``."""
    deadline = time.monotonic() + 60
    while announcement(f"ws://127.0.0.1:{port}") not in stderr.read_text():
        assert process.poll() is None, stderr.read_text()
        assert time.monotonic() < deadline, stderr.read_text()
        time.sleep(0.1)
    got = {topic: {} for topic in TOPICS}
    with FoxgloveClient(f"ws://127.0.0.1:{port}", timeout_s=60) as client:
        client.await_channels(TOPICS, timeout_s=60)
        client.subscribe_all()
        for topic, stamp, message in client.messages(
                until=lambda topic, message: topic == STATE_TOPIC and message["step"] == last_step, timeout_s=120):
            got[topic][round(stamp / 1e8)] = message
    return got


def _check_stream(got: dict, n_agents: int, size: int, summary: dict) -> None:
    steps = sorted(got[STATE_TOPIC])
    assert len(steps) >= 3 and steps[-1] == summary["steps"]
    for step in steps:
        assert got[STATE_TOPIC][step]["step"] == step
        if step in got[SCORE_TOPIC]:  # (a channel's subscription may start a step later than another's)
            assert got[SCORE_TOPIC][step]["data"] == got[STATE_TOPIC][step]["score"]
        if step in got[AGENTS_TOPIC]:
            assert len(got[AGENTS_TOPIC][step].entities) == n_agents
        if step in got[WORLD_TOPIC]:
            assert grid_cells(got[WORLD_TOPIC][step]).shape == (size, size)
    assert got[SCORE_TOPIC][steps[-1]]["data"] == summary["food"]
    assert min(len(got[topic]) for topic in TOPICS) >= 3


def test_sim_view_cli_streams_the_episode_to_a_viewer(tmp_path):
    port = _free_port()
    process = _formic(["sim", "--view", "--view-port", str(port), "--view-wait", "--policy", "csaf11",
                       "--agents", "16", "--size", "32", "--steps", "2000", "--json", "--out", str(tmp_path)],
                      tmp_path / "stderr.log")
    try:  # 2000 steps: about a second at the view's 10 Hz, so several frames follow the last subscription
        got = _watch(process, tmp_path / "stderr.log", port, 2000)
    finally:
        out = _reap(process, 120)
    assert process.returncode == 0, (tmp_path / "stderr.log").read_text()
    _check_stream(got, 16, 32, json.loads(out.strip().splitlines()[-1]))


def test_run_view_streams_a_distributed_run_and_replay_view_shows_its_recording(tmp_path):
    pytest.importorskip("rclpy")
    pytest.importorskip("formic_interfaces.msg")
    from ros_helpers import fresh_domain_id, ros_test_environment

    port, recording = _free_port(), tmp_path / "rec"
    process = _formic(["run", "--view", "--view-port", str(port), "--view-wait", "--policy", "csaf11", "--agents", "16",
                       "--size", "32", "--steps", "300", "--transport", "batched", "--rate", "100", "--json",
                       "--timeout", "100", "--record", str(recording)],
                      tmp_path / "run.log", env=ros_test_environment(fresh_domain_id()))
    try:
        got = _watch(process, tmp_path / "run.log", port, 300)
    finally:
        out = _reap(process, 120)
    assert process.returncode == 0, (tmp_path / "run.log").read_text()
    summary = json.loads(out.strip().splitlines()[-1])
    _check_stream(got, 16, 32, summary)
    # --view-wait: the world stepped only once this viewer subscribed, so its first frame is the start
    assert min(min(got[topic], default=summary["steps"]) for topic in TOPICS) == 0
    for step, score in got[SCORE_TOPIC].items():  # the world node's own score at each streamed step
        assert score["data"] == (summary["food_curve"][step - 1] if step else 0.0)

    port = _free_port()  # the recording, re-simulated into the same view at 10x sim time
    process = _formic(["replay", str(recording), "--view", "--view-port", str(port), "--view-wait", "--rate", "10",
                       "--json"], tmp_path / "replay.log")
    try:
        got = _watch(process, tmp_path / "replay.log", port, 300)
    finally:
        out = _reap(process, 60)
    assert process.returncode == 0, (tmp_path / "replay.log").read_text()
    assert json.loads(out.strip().splitlines()[-1])["steps"] == 300
    _check_stream(got, 16, 32, summary)
    for step, score in got[SCORE_TOPIC].items():  # step 0: the start, before the first step
        assert score["data"] == (summary["food_curve"][step - 1] if step else 0.0)


def test_shipped_layout_shows_the_live_channels_beside_the_recorded_topics():
    layout = json.loads((ROOT / "foxglove" / "formic_layout.json").read_text())
    panels = layout["configById"]
    three = next(v for k, v in panels.items() if k.startswith("3D!"))["topics"]
    assert three[WORLD_TOPIC] == {"visible": True, "colorMode": "rgba-fields", "frameLocked": True}
    assert three["/formic/map"]["visible"] and three[AGENTS_TOPIC]["visible"]  # recorded map; markers: both
    plot = next(v for k, v in panels.items() if k.startswith("Plot!"))
    assert f"{SCORE_TOPIC}.data" in [p["value"] for p in plot["paths"]]  # Float64.data, recorded and live
    assert f"{STATE_TOPIC}.step" in [v.get("topicPath") for v in panels.values()]  # WorldState.step and live
    assert set(CELL.names) >= {"red", "green", "blue", "alpha"}  # what rgba-fields reads
