"""Observation encodings of ObservationBatch: compact is lossless bit for bit on real
observations (finite resources, pheromones), through CDR, and about ten times smaller."""

from __future__ import annotations

import numpy as np
import pytest

rclpy_serialization = pytest.importorskip("rclpy.serialization")
msg_mod = pytest.importorskip("formic_interfaces.msg")

from conftest import agent, build_world, resource, step  # noqa: E402

from formic_ros import convert  # noqa: E402
from formic_world import World, WorldConfig, generate_scenario  # noqa: E402
from formic_world.geometry import EAST, JOIN, NORTH, WEST  # noqa: E402
from formic_world.observation import CH_PHEROMONE, CH_RESOURCE_ENTRY  # noqa: E402

pytestmark = pytest.mark.filterwarnings("ignore:module 'sre_:DeprecationWarning")


def bits(a: np.ndarray) -> bytes:
    return np.ascontiguousarray(a, dtype=np.float32).tobytes()


def fields_of(world: World, result) -> dict:
    return dict(step=world.t, observations=result.observations, action_mask=result.action_mask,
                loads=world.loads, rewards=result.rewards, queued=world.queued, positions=world.pos,
                world_shape=world.grid.shape, done=result.done)


def through_cdr(msg):
    data = rclpy_serialization.serialize_message(msg)
    return rclpy_serialization.deserialize_message(data, type(msg)), len(data)


def finite_resource_world():
    """Agent 1 gathers at spot 0 of a finite resource's queue (capacity 4 = 40 ticks, 3
    gathered): the entry behind it reads 37/40. Loaded agent 3 walks east, west, east: the
    cells it left hold decayed pheromone."""
    world = build_world([agent(4, 4), agent(2, 3), agent(7, 6, True, 0), agent(5, 5, loaded=True)],
                        resources=[resource(1, 2, EAST, 4)], obstacles=[(3, 4)])
    for move in (EAST, WEST, EAST):
        result = step(world, [NORTH, JOIN, JOIN, move])
    return world, result


def random_world(n_agents: int, size: int, steps: int, seed: int = 0) -> tuple[World, object]:
    """A generated world with finite resources after ``steps`` random moves."""
    cfg = WorldConfig(height=size, width=size, n_agents=n_agents, capacity="finite", episode_steps=steps + 1)
    world = World(generate_scenario(cfg, seed))
    result = world.reset(world.scenario)
    rng = np.random.default_rng(seed)
    for _ in range(steps):
        result = world.step(rng.integers(0, 5, n_agents))
    return world, result


# ----------------------------------------------------------------- the format itself
def test_compact_holds_a_bit_per_value_and_the_values_that_are_not_zero_or_one():
    _, result = finite_resource_world()
    obs = result.observations
    assert np.float32(37 / 40) in obs[:, CH_RESOURCE_ENTRY]
    others = obs[(obs != 0) & (obs != 1)]
    assert len(np.setdiff1d(obs[:, CH_PHEROMONE], [0, 1])) > 0
    nonzero_bits, one_bits, other_values = convert.encode_compact(obs)
    assert len(nonzero_bits) == 4 * 8 * 11 * 11 // 8
    assert len(one_bits) == (np.count_nonzero(obs) + 7) // 8
    assert bits(np.frombuffer(other_values, dtype=np.float32)) == bits(others)
    assert bits(convert.decode_compact(nonzero_bits, one_bits, other_values, obs.shape)) == bits(obs)


def test_compact_keeps_every_float_bit_for_bit():
    """Rows of 27 values (not whole bytes) holding -0.0, NaN with a payload, infinities,
    the smallest subnormal and the neighbours of 1.0."""
    special = np.array([0x80000000, 0x7FC00123, 0x7F800000, 0xFF800000, 0x00000001,
                        0x3F7FFFFF, 0x3F800001, 0x3F800000, 0xBF800000], dtype=np.uint32)
    words = np.zeros((3, 3, 3, 3), dtype=np.uint32)
    words.reshape(3, -1)[:, ::3] = special
    words[1, 2] = 0x3F800000
    obs = words.view(np.float32)
    back = convert.decode_compact(*convert.encode_compact(obs), obs.shape)
    assert back.dtype == np.float32 and back.shape == obs.shape
    assert bits(back) == bits(obs)
    empty = np.zeros((0, 8, 11, 11), dtype=np.float32)
    assert convert.decode_compact(*convert.encode_compact(empty), empty.shape).shape == empty.shape


def test_malformed_compact_fields_are_rejected():
    _, result = finite_resource_world()
    obs = result.observations
    nonzero_bits, one_bits, other_values = convert.encode_compact(obs)
    with pytest.raises(ValueError, match="nonzero bytes"):
        convert.decode_compact(nonzero_bits[:-1], one_bits, other_values, obs.shape)
    with pytest.raises(ValueError, match="one-bit bytes"):
        convert.decode_compact(nonzero_bits, one_bits + b"\0", other_values, obs.shape)
    with pytest.raises(ValueError, match="other values"):
        convert.decode_compact(nonzero_bits, one_bits, other_values[:-1], obs.shape)
    with pytest.raises(ValueError, match="unknown observation encoding"):
        convert.encoding_code("float16")
    msg = convert.observation_batch(**fields_of(*finite_resource_world()))
    msg.encoding = 7
    with pytest.raises(ValueError, match="unknown observation encoding 7"):
        convert.decode_observations(msg)


# ------------------------------------------------------------------- through messages
@pytest.mark.parametrize("encoding", ["compact", "float32"])
def test_batches_carry_the_world_observations_exactly(encoding):
    for world, result in (finite_resource_world(), random_world(16, 24, 60)):
        obs = result.observations
        assert len(np.setdiff1d(obs[:, CH_PHEROMONE], [0, 1])) > 0
        msg, _ = through_cdr(convert.observation_batch(**fields_of(world, result), encoding=encoding))
        assert msg.encoding == convert.ENCODINGS[encoding]
        assert (len(msg.data) == 0) == (encoding == "compact")
        assert bits(convert.batch_from_observation_batch(msg).observations) == bits(obs)
        rows = np.array([3, 0])
        assert bits(convert.batch_from_observation_batch(msg, rows).observations) == bits(obs[rows])
        resent, _ = through_cdr(convert.observation_batch(**fields_of(world, result), agent_ids=rows,
                                                          encoding=encoding))
        batch = convert.batch_from_observation_batch(resent)
        assert batch.agent_ids.tolist() == [3, 0] and bits(batch.observations) == bits(obs[rows])


def test_finite_resources_show_fractions_that_survive_the_trip():
    world, result = random_world(16, 24, 120, seed=1)
    obs = result.observations
    fractions = np.setdiff1d(obs[:, CH_RESOURCE_ENTRY], [0, 1])
    assert len(fractions) > 0  # some resource has been gathered from
    msg, _ = through_cdr(convert.observation_batch(**fields_of(world, result)))
    assert bits(convert.batch_from_observation_batch(msg).observations) == bits(obs)


def test_compact_is_about_ten_times_smaller():
    """The bench's setting: 128 agents in 64x64 (0.5 MB of float32 a step)."""
    world, result = random_world(128, 64, 100)
    _, plain = through_cdr(convert.observation_batch(**fields_of(world, result), encoding="float32"))
    _, compact = through_cdr(convert.observation_batch(**fields_of(world, result), encoding="compact"))
    assert plain > 128 * 8 * 11 * 11 * 4
    assert compact < plain / 6
