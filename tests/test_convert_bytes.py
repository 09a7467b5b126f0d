"""The serialized messages the per-agent transport builds itself (no message objects): the
same fields as rclpy's own serialization, both ways."""

from __future__ import annotations

import numpy as np
import pytest

pytest.importorskip("rclpy")
from rclpy import serialization  # noqa: E402
from formic_interfaces.msg import AgentAction, AgentObservation  # noqa: E402

from formic_agent.policy import AgentBatch  # noqa: E402
from formic_ros import convert  # noqa: E402
from formic_world import World, WorldConfig, generate_scenario  # noqa: E402

FIELDS = ("step", "agent_id", "channels", "size", "data", "action_mask", "load", "reward", "queued", "done", "row",
          "col", "world_height", "world_width")


def stepped_batch() -> tuple[AgentBatch, np.ndarray]:
    cfg = WorldConfig(height=24, width=24, n_agents=6, capacity="finite", episode_steps=30)
    world = World(generate_scenario(cfg, 3))
    result = world.reset(world.scenario)
    rng = np.random.default_rng(3)
    for _ in range(20):
        result = world.step(rng.integers(0, 5, 6))
    batch = AgentBatch.from_world(world, observations=result.observations, action_mask=result.action_mask)
    return batch, result.rewards


@pytest.mark.parametrize("rows", [None, np.array([4, 1])])
@pytest.mark.parametrize("done", [False, True])
def test_observation_bytes_decode_to_the_messages_rclpy_would_send(rows, done):
    batch, rewards = stepped_batch()
    built = convert.agent_observation_bytes(batch, rewards, done, rows)
    wanted = convert.encode_agent_observations(batch, rewards, done, rows)
    assert len(built) == len(wanted)
    for data, want in zip(built, wanted):
        reference = serialization.serialize_message(want)
        assert len(data) == len(reference)
        got = serialization.deserialize_message(data, AgentObservation)
        want = serialization.deserialize_message(reference, AgentObservation)
        assert [getattr(got, f) for f in FIELDS] == [getattr(want, f) for f in FIELDS]


def test_action_bytes_round_trip_through_rclpy():
    data = convert.agent_action_bytes(1023, 77, 4)
    reference = serialization.serialize_message(AgentAction(step=1023, agent_id=77, action=4))
    assert (data[:13], len(data)) == (reference[:13], len(reference))  # rclpy leaves the padding unset
    assert serialization.deserialize_message(data, AgentAction).action == 4
    assert convert.decode_agent_action(data) == (1023, 77, 4)


def test_actions_from_other_writers_decode_and_truncated_ones_do_not():
    big_endian = b"\x00\x00\x00\x00" + (9).to_bytes(4, "big") + (3).to_bytes(4, "big") + b"\x02\x00\x00\x00"
    assert convert.decode_agent_action(big_endian) == (9, 3, 2)
    assert convert.decode_agent_action(convert.agent_action_bytes(9, 3, 2)[:13]) == (9, 3, 2)  # no padding
    assert convert.decode_agent_action(convert.agent_action_bytes(9, 3, 2)[:9]) is None


def test_a_sweeps_actions_decode_as_one_array_like_one_by_one():
    datas = [convert.agent_action_bytes(9, 3, 2), convert.agent_action_bytes(9, 4, 0)[:13],  # no padding
             serialization.serialize_message(AgentAction(step=8, agent_id=5, action=4))]
    records = convert.decode_agent_actions(datas)
    assert [tuple(int(r[k]) for k in ("step", "agent_id", "action")) for r in records] == \
        [convert.decode_agent_action(d) for d in datas] == [(9, 3, 2), (9, 4, 0), (8, 5, 4)]
    big_endian = b"\x00\x00\x00\x00" + (9).to_bytes(4, "big") + (3).to_bytes(4, "big") + b"\x02\x00\x00\x00"
    assert convert.decode_agent_actions(datas + [big_endian]) is None  # read one by one instead
    assert convert.decode_agent_actions(datas + [datas[0][:9]]) is None
    assert len(convert.decode_agent_actions([])) == 0


@pytest.mark.parametrize("done", [False, True])
def test_observation_bytes_decode_as_one_batch_like_the_messages(done):
    batch, rewards = stepped_batch()
    rows = np.array([5, 0, 2])
    built = convert.agent_observation_bytes(batch, rewards, done, rows)
    heads = [convert.agent_observation_head(data) for data in built]
    assert [(step, agent, flag) for _, step, agent, flag in heads] == [(batch.step, a, done) for a in (5, 0, 2)]
    got = convert.decode_agent_observation_bytes([data for data, *_ in heads])
    want = convert.decode_agent_observations(
        [serialization.deserialize_message(serialization.serialize_message(m), AgentObservation)
         for m in convert.encode_agent_observations(batch, rewards, done, rows)])
    assert (got.step, got.world_shape) == (want.step, want.world_shape)
    for name in ("agent_ids", "observations", "action_mask", "positions", "loads", "queued"):
        value = getattr(got, name)
        assert value.dtype == getattr(want, name).dtype and value.flags.writeable
        np.testing.assert_array_equal(value, getattr(want, name))


def test_observations_from_other_writers_are_laid_out_again_and_bad_ones_refused():
    batch, rewards = stepped_batch()
    message = convert.encode_agent_observations(batch, rewards, False, np.array([3]))[0]
    data = serialization.serialize_message(message)
    head = convert.agent_observation_head(data[:-1])  # truncated: not this layout, and rclpy refuses it
    assert head is None
    message.action_mask = b"\x01\x01"
    assert convert.agent_observation_head(serialization.serialize_message(message)) is None
