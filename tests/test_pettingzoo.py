"""The PettingZoo ParallelEnv: API conformance, seeding, truncation and agents left out of a step."""

from __future__ import annotations

import numpy as np
import pytest
from gymnasium import spaces
from pettingzoo.test import parallel_api_test, parallel_seed_test

from formic_world import World, WorldConfig, generate_scenario, parallel_env
from formic_world.geometry import EAST
from formic_world.pettingzoo_env import FormicParallelEnv
from formic_world.render import render_frame
from formic_world.scenario import AgentStart, ResourceSpec, Scenario

SMALL = dict(height=16, width=16, n_agents=4, episode_steps=30)


def test_parallel_api():
    env = parallel_env(**SMALL, render_mode="rgb_array")
    parallel_api_test(env, num_cycles=40)
    assert env.agents == []


def test_parallel_seed():
    parallel_seed_test(lambda: parallel_env(**SMALL), num_cycles=40)


def test_config_keywords_and_spaces():
    env = parallel_env(height=24, width=24, n_agents=4, max_cycles=7)
    assert isinstance(env, FormicParallelEnv) and env.metadata["name"] == "formic_v0"
    assert env.config == WorldConfig(height=24, width=24, n_agents=4)
    assert env.max_cycles == 7 and parallel_env(**SMALL).max_cycles == 30
    assert env.possible_agents == ["agent_0", "agent_1", "agent_2", "agent_3"]
    assert env.observation_space("agent_2") == spaces.Box(0.0, 1.0, (8, 11, 11), np.float32)
    assert env.action_space("agent_0") == spaces.Discrete(5)
    with pytest.raises(ValueError, match="render_mode"):
        parallel_env(**SMALL, render_mode="human")
    with pytest.raises(ValueError, match="highway_intensity"):
        parallel_env(**SMALL, highway_intensity=1.5)


def test_reset_plays_the_seeded_scenario_and_matches_the_core():
    cfg = WorldConfig(**SMALL)
    env = parallel_env(**SMALL)
    obs, infos = env.reset(seed=5)
    world = World(generate_scenario(cfg, 5))
    rng = np.random.default_rng(0)
    for _ in range(10):
        actions = rng.integers(0, 5, size=4)
        obs, rewards, _, _, infos = env.step({f"agent_{i}": int(a) for i, a in enumerate(actions)})
        result = world.step(actions)
    assert env.world.state_digest() == world.state_digest()
    for i in range(4):
        name = f"agent_{i}"
        assert np.array_equal(obs[name], result.observations[i])
        assert rewards[name] == result.rewards[i]
        assert infos[name]["action_mask"].dtype == np.int8
        assert np.array_equal(infos[name]["action_mask"], result.action_mask[i].astype(np.int8))
        assert infos[name]["load"] == world.loads[i] and infos[name]["queued"] == world.queued[i]
        assert np.array_equal(infos[name]["position"], world.pos[i])
    env.reset()  # without a seed: the next seed
    assert env.scenario_seed == 6
    assert env.world.state_digest() == World(generate_scenario(cfg, 6)).state_digest()


def test_observations_and_state_stay_in_their_boxes():
    env = parallel_env(**SMALL, training_start=True, highway_intensity=1.0, deposit_strength=1.0)
    obs, _ = env.reset(seed=1)
    rng = np.random.default_rng(1)
    seen_pheromone = 0.0
    while env.agents:
        for agent, o in obs.items():
            assert env.observation_space(agent).contains(o)
            seen_pheromone = max(seen_pheromone, float(o[7].max()))
        assert env.state_space.contains(env.state())
        obs, *_ = env.step({a: int(rng.integers(0, 5)) for a in env.agents})
    assert seen_pheromone > 0


def test_truncation_at_max_cycles_empties_the_agents():
    env = parallel_env(**SMALL, max_cycles=3)
    env.reset(seed=0)
    for t in range(3):
        _, _, terminations, truncations, _ = env.step({a: 0 for a in env.agents})
        assert not any(terminations.values())
        assert all(truncations.values()) == (t == 2)
    assert env.agents == [] and env.world.t == 3
    assert env.step({}) == ({}, {}, {}, {}, {})
    env.reset(seed=0)
    with pytest.raises(ValueError, match="not live"):
        env.step({"agent_9": 0})


def test_stored_scenario_through_options():
    env = parallel_env(**SMALL)
    scenario = generate_scenario(WorldConfig(**SMALL).replace(wipeouts=0, obstacle_density=0.05), 3)
    env.reset(options={"scenario": scenario})
    assert env.world.scenario is scenario and env.scenario_seed == 3
    with pytest.raises(ValueError, match="n_agents"):
        env.reset(options={"scenario": generate_scenario(WorldConfig(**SMALL).replace(n_agents=5), 0)})


def test_render_and_state():
    env = parallel_env(**SMALL, render_mode="rgb_array")
    env.reset(seed=2)
    assert np.array_equal(env.render(), render_frame(env.world))
    state = env.state()
    assert state.shape == (8, 16, 16) and state.dtype == np.float32
    assert np.array_equal(state[2], (env.world.grid != 0).astype(np.float32))
    quiet = parallel_env(**SMALL)
    quiet.reset(seed=2)
    assert quiet.render() is None


# Nest caches at rows 7-8, cols 7-8: queues run W from (7,6), N from (6,8), S from (9,7), E from
# (8,9). Resource 0 at (1,1), its queue running east from (1,2) (the entry while it is empty).
IDLE_AGENTS = (
    AgentStart(0, 12, False, -1),  # 0: top edge: north certainly fails
    AgentStart(12, 12, False, -1),  # 1: open, no queue cell in reach: JOIN finds nothing
    AgentStart(3, 9, False, -1),  # 2: beside NE queue cell (3,8), agent 3 to its east
    AgentStart(3, 10, False, -1),  # 3: open, no queue cell in reach: JOIN
    AgentStart(11, 8, False, -1),  # 4: beside SW queue cell (11,7), JOIN invalid
    AgentStart(2, 2, False, -1),  # 5: beside the resource's entry, JOIN valid: cannot stay
    AgentStart(7, 6, True, 0),  # 6: queued at the NW cache
    AgentStart(6, 6, False, -1),  # 7: the queued agent 6 to its south
)
IDLE_SCENARIO = Scenario(
    WorldConfig(height=16, width=16, n_agents=8), 0, obstacles=(), resources=(ResourceSpec(1, 1, 1, 0),),
    agents=IDLE_AGENTS, wipeout_starts=(),
)


def test_agents_left_out_of_a_step_stay_put():
    env = parallel_env(height=16, width=16, n_agents=8)
    env.reset(options={"scenario": IDLE_SCENARIO})
    before = env.world.pos.copy()
    _, rewards, *_ = env.step({"agent_1": EAST})
    moved = np.flatnonzero((env.world.pos != before).any(axis=1)).tolist()
    assert moved == [1]  # only agent 1 acted; the others did nothing
    assert rewards["agent_0"] == 0.0 and rewards["agent_5"] == 0.0  # no action, no cost
