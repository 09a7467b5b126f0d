"""The codec: every encode has its decode (round trips through CDR), and the observation
encodings of ObservationBatch and Rollout: compact is lossless bit for bit on real observations
(finite resources, pheromones), through CDR, and over ten times smaller."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

rclpy_serialization = pytest.importorskip("rclpy.serialization")
msg_mod = pytest.importorskip("formic_interfaces.msg")

from conftest import agent, build_world, resource, step  # noqa: E402

from formic_agent.policy import AgentBatch  # noqa: E402
from formic_record import compact  # noqa: E402
from formic_record.replay import RecordedState  # noqa: E402
from formic_ros import convert, convert_learning, wire  # noqa: E402
from formic_topics import EXTRA_INPUT_COUNT  # noqa: E402
from formic_trainer.rollout import Rollout  # noqa: E402
from formic_world import World, WorldConfig, generate_scenario  # noqa: E402
from formic_world.geometry import EAST, JOIN, NORTH, WEST  # noqa: E402
from formic_world.observation import CH_PHEROMONE, CH_RESOURCE_ENTRY  # noqa: E402

pytestmark = pytest.mark.filterwarnings("ignore:module 'sre_:DeprecationWarning")


def bits(a: np.ndarray) -> bytes:
    return np.ascontiguousarray(a, dtype=np.float32).tobytes()


def encode(world: World, result, **kw):
    batch = AgentBatch.from_world(world, observations=result.observations, action_mask=result.action_mask)
    return convert.encode_observation_batch(batch, result.rewards, result.done, **kw)


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
    nonzero_bits, one_bits, other_values = compact.encode_compact(obs)
    assert len(nonzero_bits) == 4 * 8 * 11 * 11 // 8
    assert len(one_bits) == (np.count_nonzero(obs) + 7) // 8
    assert bits(np.frombuffer(other_values, dtype=np.float32)) == bits(others)
    assert bits(compact.decode_compact(nonzero_bits, one_bits, other_values, obs.shape)) == bits(obs)
    # as rclpy hands the fields over (bytes, array.array) and as a bag reader does (NumPy arrays)
    fields = wire.observation_fields(obs, "compact")
    assert isinstance(fields["nonzero_bits"], bytes)
    assert bits(compact.decode_compact(fields["nonzero_bits"], fields["one_bits"], fields["other_values"],
                                       obs.shape)) == bits(obs)


def test_compact_keeps_every_float_bit_for_bit():
    """Rows of 27 values (not whole bytes) holding -0.0, NaN with a payload, infinities,
    the smallest subnormal and the neighbours of 1.0."""
    special = np.array([0x80000000, 0x7FC00123, 0x7F800000, 0xFF800000, 0x00000001,
                        0x3F7FFFFF, 0x3F800001, 0x3F800000, 0xBF800000], dtype=np.uint32)
    words = np.zeros((3, 3, 3, 3), dtype=np.uint32)
    words.reshape(3, -1)[:, ::3] = special
    words[1, 2] = 0x3F800000
    obs = words.view(np.float32)
    back = compact.decode_compact(*compact.encode_compact(obs), obs.shape)
    assert back.dtype == np.float32 and back.shape == obs.shape
    assert bits(back) == bits(obs)
    empty = np.zeros((0, 8, 11, 11), dtype=np.float32)
    assert compact.decode_compact(*compact.encode_compact(empty), empty.shape).shape == empty.shape


def test_malformed_compact_fields_are_rejected():
    _, result = finite_resource_world()
    obs = result.observations
    nonzero_bits, one_bits, other_values = compact.encode_compact(obs)
    with pytest.raises(ValueError, match="nonzero bytes"):
        compact.decode_compact(nonzero_bits[:-1], one_bits, other_values, obs.shape)
    with pytest.raises(ValueError, match="one-bit bytes"):
        compact.decode_compact(nonzero_bits, np.append(one_bits, np.uint8(0)), other_values, obs.shape)
    with pytest.raises(ValueError, match="other values"):
        compact.decode_compact(nonzero_bits, one_bits, other_values[:-1], obs.shape)
    with pytest.raises(ValueError, match="unknown observation encoding"):
        wire.encoding_code("float16")
    msg = encode(*finite_resource_world())
    msg.encoding = 7
    with pytest.raises(ValueError, match="unknown observation encoding 7"):
        wire.decode_observations(msg)


# ------------------------------------------------------------------- through messages
@pytest.mark.parametrize("encoding", ["compact", "float32"])
def test_batches_carry_the_world_observations_exactly(encoding):
    for world, result in (finite_resource_world(), random_world(16, 24, 60)):
        obs = result.observations
        assert len(np.setdiff1d(obs[:, CH_PHEROMONE], [0, 1])) > 0
        msg, _ = through_cdr(encode(world, result, encoding=encoding))
        assert msg.encoding == wire.ENCODINGS[encoding]
        assert (len(msg.data) == 0) == (encoding == "compact")
        assert bits(convert.decode_observation_batch(msg).observations) == bits(obs)
        rows = np.array([3, 0])
        assert bits(convert.decode_observation_batch(msg, rows).observations) == bits(obs[rows])
        resent, _ = through_cdr(encode(world, result, rows=rows, encoding=encoding))
        batch = convert.decode_observation_batch(resent)
        assert batch.agent_ids.tolist() == [3, 0] and bits(batch.observations) == bits(obs[rows])


def test_finite_resources_show_fractions_that_survive_the_trip():
    world, result = random_world(16, 24, 120, seed=1)
    obs = result.observations
    fractions = np.setdiff1d(obs[:, CH_RESOURCE_ENTRY], [0, 1])
    assert len(fractions) > 0  # some resource has been gathered from
    msg, _ = through_cdr(encode(world, result))
    assert bits(convert.decode_observation_batch(msg).observations) == bits(obs)


def test_compact_is_about_ten_times_smaller():
    """The bench's setting: 128 agents in 64x64 (0.5 MB of float32 a step)."""
    world, result = random_world(128, 64, 100)
    _, plain = through_cdr(encode(world, result, encoding="float32"))
    _, compact = through_cdr(encode(world, result, encoding="compact"))
    assert plain > 128 * 8 * 11 * 11 * 4
    assert compact < plain / 6


# ------------------------------------------------------------------- round trips
def test_agent_batches_round_trip_batched_and_per_agent():
    world, result = random_world(6, 24, 20)
    batch = AgentBatch.from_world(world, observations=result.observations, action_mask=result.action_mask)
    rows = np.array([4, 1])
    batched, _ = through_cdr(convert.encode_observation_batch(batch, result.rewards, result.done))
    per_agent = [through_cdr(m)[0] for m in convert.encode_agent_observations(batch, result.rewards, result.done, rows)]
    for got, want_rows in ((convert.decode_observation_batch(batched), slice(None)),
                           (convert.decode_observation_batch(batched, rows), rows),
                           (convert.decode_agent_observations(per_agent), rows)):
        assert got.step == batch.step and got.world_shape == batch.world_shape
        for name in ("agent_ids", "observations", "action_mask", "positions", "queued"):
            np.testing.assert_array_equal(getattr(got, name), getattr(batch, name)[want_rows])
        np.testing.assert_array_equal(got.loads.astype(np.float32), batch.loads[want_rows].astype(np.float32))
    assert wire.read(batched.rewards, np.float32).tolist() == result.rewards.astype(np.float32).tolist()
    assert [m.reward for m in per_agent] == result.rewards[rows].astype(np.float32).tolist()


def test_actions_round_trip_with_no_action():
    msg, _ = through_cdr(convert.encode_actions(7, np.array([5, 2, 9]), np.array([2, -1, 4])))
    assert bytes(msg.actions) == bytes([2, 255, 4])
    step, ids, actions = convert.decode_actions(msg)
    assert (step, ids.tolist(), actions.tolist()) == (7, [5, 2, 9], [2, -1, 4])
    applied, _ = through_cdr(convert.encode_applied(3, np.array([0, -1, 1])))
    assert convert.decode_applied(applied, 3).tolist() == [0, -1, 1]


def test_scenario_and_state_round_trip():
    world, _ = random_world(4, 16, 5)
    msg, _ = through_cdr(convert.encode_scenario(world.scenario, "random"))
    assert convert.decode_scenario(msg).to_json() == world.scenario.to_json()
    state, _ = through_cdr(convert.encode_state(world, np.zeros(4)))
    from formic_record.replay import difference_from

    assert difference_from(world, RecordedState.from_message(state)) is None


def random_rollout(imitation: bool, steps: int = 3, agents: int = 2, rnn: int = 4) -> Rollout:
    """Random values; the observations mostly 0 and 1, with fractions, -0.0, a NaN with a
    payload and an infinity among them."""
    rng = np.random.default_rng(0)

    def floats(*shape: int) -> np.ndarray:
        return rng.random(shape, dtype=np.float32)

    def flags(*shape: int) -> np.ndarray:
        return rng.random(shape) < 0.5

    observations = floats(steps + 1, agents, 8, 11, 11)
    observations[observations < 0.6] = 0.0
    observations[observations > 0.9] = 1.0
    observations.view(np.uint32).reshape(-1)[[5, 77, 300]] = [0x80000000, 0x7FC00123, 0x7F800000]
    return Rollout(
        weights_version=3, episode=2, done=True, food=1.5, agent_ids=np.array([5, 7][:agents], dtype=np.int64),
        observations=observations, extra_inputs=floats(steps + 1, agents, EXTRA_INPUT_COUNT),
        actions=rng.integers(0, 5, (steps, agents)), logprobs=floats(steps, agents), values=floats(steps, agents),
        next_value=floats(agents), h0=floats(1, agents, rnn), c0=floats(1, agents, rnn), rewards=floats(steps, agents),
        train_mask=flags(steps, agents, 5), sample_mask=flags(steps, agents, 5), loss_mask=flags(steps, agents),
        value_mask=flags(steps, agents),
        expert_actions=rng.integers(0, 5, (steps, agents)) if imitation else None,
        imitation_mask=flags(steps, agents) if imitation else None,
    )


@pytest.mark.parametrize("encoding", ["compact", "float32"])
@pytest.mark.parametrize("imitation", [False, True])
def test_rollouts_round_trip_field_for_field(imitation, encoding):
    """Every field comes back bit for bit (the learner's losses depend on it), in either encoding."""
    want = random_rollout(imitation)
    msg, _ = through_cdr(convert_learning.encode_rollout(want, encoding))
    assert (msg.n_steps, msg.n_agents, msg.encoding) == (3, 2, wire.ENCODINGS[encoding])
    assert (len(msg.observations) == 0) == (encoding == "compact")
    got = convert_learning.decode_rollout(msg)
    for field in dataclasses.fields(Rollout):
        a, b = getattr(got, field.name), getattr(want, field.name)
        if isinstance(b, np.ndarray):
            assert a.dtype == b.dtype and a.shape == b.shape and a.tobytes() == b.tobytes(), field.name
        else:
            assert a == b and type(a) is type(b), field.name
    for name in ("rewards", "h0", "train_mask"):
        broken, _ = through_cdr(convert_learning.encode_rollout(want, encoding))
        setattr(broken, name, getattr(broken, name)[:-1])
        with pytest.raises(ValueError, match=f"Rollout.{name}"):
            convert_learning.decode_rollout(broken)
    broken, _ = through_cdr(convert_learning.encode_rollout(want, encoding))
    field = "other_values" if encoding == "compact" else "observations"
    setattr(broken, field, getattr(broken, field)[:-1])
    with pytest.raises(ValueError, match="other values" if encoding == "compact" else "float32 observation values"):
        convert_learning.decode_rollout(broken)


def test_a_rollout_of_world_observations_is_over_ten_times_smaller_compact():
    """A chunk of a real world's frames (16 agents, 32x32, pheromones and resource fractions):
    compact carries it exactly in under a tenth of the float32 bytes (what lets rollouts cross a
    lossy link, docs/ros.md)."""
    world = World(generate_scenario(WorldConfig(height=32, width=32, n_agents=16, capacity="finite",
                                                episode_steps=40), 0))
    frames = [world.reset(world.scenario).observations]
    rng = np.random.default_rng(0)
    for _ in range(31):
        frames.append(world.step(rng.integers(0, 5, 16)).observations)
    want = dataclasses.replace(random_rollout(False, steps=31, agents=16), agent_ids=np.arange(16),
                               observations=np.stack(frames))
    sizes = {}
    for encoding in ("float32", "compact"):
        msg, sizes[encoding] = through_cdr(convert_learning.encode_rollout(want, encoding))
        assert bits(convert_learning.decode_rollout(msg).observations) == bits(want.observations)
    assert sizes["compact"] < sizes["float32"] / 10, sizes


def test_weights_round_trip():
    want = convert_learning.WeightsPayload(4, b"\x00\x01weights", "abc123", {"channels": 8, "hidden": [64, 64]})
    msg, _ = through_cdr(convert_learning.encode_weights(want))
    assert convert_learning.decode_weights(msg) == want
