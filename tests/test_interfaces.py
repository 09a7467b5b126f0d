"""formic_interfaces: every message round-trips through CDR, and third-party readers decode it.

Array fields are filled with array.array / bytes (what production code should assign: fast).
"""

from __future__ import annotations

import array
import io
import math
from pathlib import Path

import pytest

rclpy_serialization = pytest.importorskip("rclpy.serialization")
msg_mod = pytest.importorskip("formic_interfaces.msg")

# lark (used by the ROS type-description code) imports deprecated re internals on first use.
pytestmark = pytest.mark.filterwarnings("ignore:module 'sre_:DeprecationWarning")

MSG_DIR = Path(__file__).resolve().parents[1] / "ros2_ws" / "formic_interfaces" / "msg"

C, S = 4, 11  # observation channels, window size
N = 3  # agents in batches
T = 2  # rollout steps


def f32(n: int, scale: float = 0.25) -> array.array:
    """n float32 values that are exact in float32 (so equality is exact)."""
    return array.array("f", [(i % 97) * scale - 3.0 for i in range(n)])


def u8(n: int, mod: int = 256) -> bytes:
    return bytes(i % mod for i in range(n))


SAMPLES = {
    "AgentObservation": dict(
        step=4_000_000_000,
        agent_id=31,
        channels=C,
        size=S,
        data=f32(C * S * S),
        action_mask=bytes([1, 0, 1, 1, 0]),
        load=0.5,
        reward=-1.25,
        queued=True,
        done=True,
        row=-3,
        col=127,
        world_height=128,
        world_width=96,
    ),
    "AgentAction": dict(step=12345, agent_id=7, action=4),
    "ObservationBatch": dict(
        step=99,
        agent_ids=array.array("I", [0, 5, 2**32 - 1]),
        channels=C,
        size=S,
        encoding=1,
        data=f32(N * C * S * S),
        nonzero_bits=u8(N * (C * S * S + 7) // 8),
        one_bits=u8(40),
        other_values=f32(17, 0.125),
        action_masks=u8(N * 5, 2),
        loads=array.array("f", [0.0, 1.0, 0.5]),
        rewards=array.array("f", [0.0, -0.25, 10.0]),
        queued=bytes([0, 1, 0]),
        done=True,
        rows=array.array("i", [1, 2, 3]),
        cols=array.array("i", [4, 5, -6]),
        world_height=64,
        world_width=64,
        train_masks=u8(N * 5, 3),
    ),
    "ActionBatch": dict(
        step=100,
        agent_ids=array.array("I", [0, 5, 9]),
        actions=bytes([0, 3, 4]),
    ),
    "WorldState": dict(
        step=512,
        height=4,
        width=5,
        score=1234.5678901234,
        grid=u8(20, 4),
        pheromone=f32(20, 0.125),
        agent_rows=array.array("i", [0, 3, -1]),
        agent_cols=array.array("i", [4, 2, 2**31 - 1]),
        agent_loads=array.array("f", [0.0, 1.0, 0.75]),
        agent_queues=array.array("i", [-1, 0, 1]),
        resource_rows=array.array("i", [1, 2]),
        resource_cols=array.array("i", [3, 0]),
        resource_directions=bytes([0, 3]),
        resource_remaining=array.array("f", [-1.0, 17.0]),
        missed_actions=array.array("I", [0, 2, 2**32 - 1]),
        state_digest="sha256:" + "ab" * 32,
    ),
    "ScenarioDescription": dict(
        format_version=1,
        seed=2**64 - 1,
        config_digest="0123456789abcdef",
        scenario_json='{"map": "ants", "agents": 32, "name": "fourmi \\u00e9\u00e9"}',
        policies="formic:0-31",
    ),
    "Rollout": dict(
        n_agents=N,
        n_steps=T,
        channels=C,
        size=S,
        weights_version=17,
        episode=3,
        done=True,
        food=42.0,
        agent_ids=array.array("I", [0, 1, 2]),
        encoding=0,
        observations=f32((T + 1) * N * C * S * S),
        nonzero_bits=u8(7),
        one_bits=u8(3),
        other_values=f32(5, 0.5),
        extra_inputs=f32((T + 1) * N * 10, 0.25),
        actions=u8(T * N, 5),
        logprobs=f32(T * N, -0.125),
        values=f32(T * N, 0.5),
        next_value=f32(N, 0.5),
        h0=f32(N * 4, 0.125),
        c0=f32(N * 4, -0.125),
        rewards=f32(T * N, 0.5),
        train_mask=u8(T * N * 5, 2),
        sample_mask=u8(T * N * 5, 2),
        loss_mask=bytes([1, 1, 0, 1, 1, 1]),
        value_mask=bytes([1, 0, 1, 1, 1, 1]),
        expert_actions=u8(T * N, 5),
        imitation_mask=bytes([0, 1, 1, 0, 1, 1]),
    ),
    "Weights": dict(
        version=5,
        model_config_json='{"hidden": 64}',
        checkpoint_id="ckpt-000005",
        data=bytes(range(256)) * 64,
    ),
    "RobotGoal": dict(
        agent_id=29,
        step=-1,
        attempt=2,
        rows=array.array("i", [4, 3]),
        cols=array.array("i", [7, 7]),
        xs=array.array("d", [3.75, 3.75]),
        ys=array.array("d", [13.75, 14.25]),
        tolerance=0.1,
        timeout_s=2.5,
        cell_size=0.5,
        origin_x=-1.5,
        origin_y=2.25,
        height=32,
        width=31,
    ),
    "RobotStatus": dict(
        agent_id=29,
        step=41,
        attempt=1,
        status=2,
        row=-1,
        col=-1,
        x=3.7625,
        y=-14.125,
        yaw=-3.0,
        distance=0.0625,
    ),
}


def as_plain(value):
    """A comparable form of a field value from either rclpy or mcap_ros2."""
    if isinstance(value, (array.array, bytes, bytearray, list, tuple)):
        return list(value)
    if hasattr(value, "tolist"):  # numpy
        return value.tolist()
    return value


def make(name: str):
    cls = getattr(msg_mod, name)
    msg = cls()
    for field, value in SAMPLES[name].items():
        setattr(msg, field, value)
    return cls, msg


def test_samples_cover_every_field():
    """Each sample sets every field of its message (and every message has a sample)."""
    names = {p.stem for p in MSG_DIR.glob("*.msg")}
    assert names == set(SAMPLES)
    for name in names:
        cls = getattr(msg_mod, name)
        assert set(cls.get_fields_and_field_types()) == set(SAMPLES[name]), name


@pytest.mark.parametrize("name", sorted(SAMPLES))
def test_cdr_round_trip(name):
    cls, msg = make(name)
    data = rclpy_serialization.serialize_message(msg)
    back = rclpy_serialization.deserialize_message(data, cls)
    for field, value in SAMPLES[name].items():
        got = getattr(back, field)
        if isinstance(value, float):
            assert got == value, field
            assert not math.isnan(got)
        else:
            assert as_plain(got) == as_plain(value), field
    assert back == msg


def test_array_fields_are_array_backed():
    """uint8[] / float32[] fields hold array.array, so np.frombuffer reads them without copying."""
    import numpy as np

    _, msg = make("ObservationBatch")
    back = rclpy_serialization.deserialize_message(
        rclpy_serialization.serialize_message(msg), msg_mod.ObservationBatch
    )
    assert isinstance(back.data, array.array) and back.data.typecode == "f"
    assert isinstance(back.action_masks, array.array) and back.action_masks.typecode == "B"
    obs = np.frombuffer(back.data, dtype=np.float32).reshape(N, C, S, S)
    assert obs[1, 2, 3, 4] == SAMPLES["ObservationBatch"]["data"][((1 * C + 2) * S + 3) * S + 4]


def test_mcap_ros2_decodes_our_types():
    """A third-party reader (mcap_ros2, no rclpy involved) decodes our CDR with the .msg text."""
    from mcap.reader import make_reader
    from mcap.writer import Writer
    from mcap_ros2.decoder import DecoderFactory

    buf = io.BytesIO()
    writer = Writer(buf)
    writer.start(profile="ros2", library="formic-tests")
    for i, name in enumerate(sorted(SAMPLES)):
        schema_id = writer.register_schema(
            name=f"formic_interfaces/msg/{name}",
            encoding="ros2msg",
            data=(MSG_DIR / f"{name}.msg").read_bytes(),
        )
        channel_id = writer.register_channel(
            topic=f"/test/{name}", message_encoding="cdr", schema_id=schema_id
        )
        _, msg = make(name)
        writer.add_message(
            channel_id=channel_id,
            log_time=i,
            publish_time=i,
            data=rclpy_serialization.serialize_message(msg),
        )
    writer.finish()

    buf.seek(0)
    reader = make_reader(buf, decoder_factories=[DecoderFactory()])
    seen = set()
    for schema, _channel, _message, decoded in reader.iter_decoded_messages():
        name = schema.name.rsplit("/", 1)[-1]
        seen.add(name)
        for field, value in SAMPLES[name].items():
            assert as_plain(getattr(decoded, field)) == as_plain(value), (name, field)
    assert seen == set(SAMPLES)


def test_observation_encodings():
    """ObservationBatch and Rollout name the same encodings (formic_topics restates them for readers
    without ROS); a message that only fills its float32 field is float32."""
    import formic_topics

    for cls in (msg_mod.ObservationBatch, msg_mod.Rollout):
        assert (cls.ENCODING_FLOAT32, cls.ENCODING_COMPACT) == (
            formic_topics.ENCODING_FLOAT32, formic_topics.ENCODING_COMPACT) == (0, 1)
        assert cls().encoding == cls.ENCODING_FLOAT32
