"""Controlling `formic world` like any ROS 2 simulator (simulation_interfaces, docs/ros.md
"Control the world"), and every node's settings as ROS parameters. The client here uses only
the standard interfaces (simulation_interfaces, rcl_interfaces parameter services): a paused
world stepped by service and by action, a reset with a seed and a played episode all end in
`formic sim`'s state digest for the same seed and steps. Real processes, own ROS domain,
UDPv4, small worlds, every process bounded and reaped."""

from __future__ import annotations

import contextlib
import re
import time

import numpy as np
import pytest

rclpy = pytest.importorskip("rclpy")
pytest.importorskip("simulation_interfaces.srv")

from rcl_interfaces.msg import Parameter as ParameterMsg  # noqa: E402
from rcl_interfaces.msg import ParameterType, ParameterValue  # noqa: E402
from rcl_interfaces.srv import GetParameters, ListParameters, SetParameters  # noqa: E402
from rclpy.action import ActionClient  # noqa: E402
from simulation_interfaces.action import SimulateSteps  # noqa: E402
from simulation_interfaces.msg import (Bounds, EntityCategory, EntityFilters, Result, SimulationState,  # noqa: E402
                                       SimulatorFeatures, TagsFilter)
from simulation_interfaces.srv import (GetEntities, GetEntitiesStates, GetEntityInfo, GetEntityState,  # noqa: E402
                                       GetSimulationState, GetSimulatorFeatures, ResetSimulation,
                                       SetSimulationState, StepSimulation)
from geometry_msgs.msg import Vector3  # noqa: E402
from ros_helpers import ROOT, Spawner, fresh_domain_id, ros_test_environment  # noqa: E402

from formic_ros.parameters import parameter_value  # noqa: E402
from formic_ros.world.entities import FilterError, select, world_entities  # noqa: E402
from formic_runtime.episode import run_episode  # noqa: E402
from formic_world import World, WorldConfig, generate_scenario  # noqa: E402
from formic_world.metric_frame import MetricFrame  # noqa: E402

pytestmark = pytest.mark.filterwarnings("ignore:module 'sre_:DeprecationWarning")

SIZE, AGENTS, STEPS = 32, 8, 30
WORLD = ["--agents", str(AGENTS), "--size", str(SIZE), "--steps", str(STEPS)]
PAUSED, PLAYING = SimulationState.STATE_PAUSED, SimulationState.STATE_PLAYING
OK, FAILED = Result.RESULT_OK, Result.RESULT_OPERATION_FAILED


def sim_world(seed: int) -> World:
    """`formic sim --policy random` of the test world: the final world."""
    scenario = generate_scenario(WorldConfig(height=SIZE, width=SIZE, n_agents=AGENTS, episode_steps=STEPS), seed)
    return run_episode(scenario, "random").world


class StandardClient:
    """A node in this test's process that talks to the world through the standard interfaces only."""

    def __init__(self, node, executor):
        self.node, self.executor = node, executor
        self.clients = {}

    def call(self, srv_type, name: str, request=None, timeout: float = 60.0):
        if name not in self.clients:
            self.clients[name] = self.node.create_client(srv_type, name)
            assert self.clients[name].wait_for_service(timeout_sec=30.0), f"no service {name}"
        future = self.clients[name].call_async(request if request is not None else srv_type.Request())
        self.executor.spin_until_future_complete(future, timeout_sec=timeout)
        assert future.done(), f"{name} did not answer in {timeout} s"
        return future.result()

    def step(self, steps: int) -> Result:
        return self.call(StepSimulation, "/formic/step_simulation", StepSimulation.Request(steps=steps)).result

    def set_state(self, state: int) -> Result:
        request = SetSimulationState.Request(state=SimulationState(state=state))
        return self.call(SetSimulationState, "/formic/set_simulation_state", request).result

    def state(self) -> int:
        return self.call(GetSimulationState, "/formic/get_simulation_state").state.state

    def simulate(self, steps: int) -> tuple[Result, list[tuple[int, int]]]:
        """The SimulateSteps action: its result and every feedback (completed, remaining)."""
        action = ActionClient(self.node, SimulateSteps, "/formic/simulate_steps")
        assert action.wait_for_server(timeout_sec=30.0)
        feedback = []
        sent = action.send_goal_async(SimulateSteps.Goal(steps=steps), feedback_callback=lambda m: feedback.append(
            (m.feedback.completed_steps, m.feedback.remaining_steps)))
        self.executor.spin_until_future_complete(sent, timeout_sec=30.0)
        done = sent.result().get_result_async()
        self.executor.spin_until_future_complete(done, timeout_sec=60.0)
        assert done.done(), "SimulateSteps did not finish"
        until = time.monotonic() + 1.0  # feedback may trail the result (another topic)
        while (steps, 0) not in feedback and time.monotonic() < until:
            self.executor.spin_once(timeout_sec=0.05)
        return done.result().result.result, feedback

    def agent_cells(self, frame: MetricFrame) -> np.ndarray:
        """Every agent's (row, col), from its pose in the map frame."""
        answer = self.call(GetEntitiesStates, "/formic/get_entities_states",
                           GetEntitiesStates.Request(filters=EntityFilters(filter="^agent_")))
        assert answer.result.result == OK and answer.entities == [f"agent_{a}" for a in range(AGENTS)]
        assert {s.header.frame_id for s in answer.states} == {"map"}
        return np.array([frame.cell_at(s.pose.position.x, s.pose.position.y) for s in answer.states])

    def parameters(self, node: str) -> dict[str, ParameterValue]:
        names = self.call(ListParameters, f"{node}/list_parameters").result.names
        values = self.call(GetParameters, f"{node}/get_parameters", GetParameters.Request(names=names)).values
        return dict(zip(names, values))

    def set_parameter(self, node: str, name: str, value: ParameterValue):
        request = SetParameters.Request(parameters=[ParameterMsg(name=name, value=value)])
        return self.call(SetParameters, f"{node}/set_parameters", request).results[0]


@contextlib.contextmanager
def standard_client(domain_id: int, monkeypatch):
    from rclpy.executors import SingleThreadedExecutor

    env = ros_test_environment(domain_id)
    for key in ("FASTDDS_BUILTIN_TRANSPORTS", "ROS_AUTOMATIC_DISCOVERY_RANGE"):
        monkeypatch.setenv(key, env[key])
    context = rclpy.Context()
    rclpy.init(context=context, domain_id=domain_id)
    node = rclpy.create_node("standard_client", context=context)
    executor = SingleThreadedExecutor(context=context)
    executor.add_node(node)
    try:
        yield StandardClient(node, executor)
    finally:
        executor.shutdown()
        node.destroy_node()
        rclpy.try_shutdown(context=context)


def summaries(proc) -> list[dict]:
    import json

    return [json.loads(line) for line in proc.output().splitlines() if line.startswith("{")]


def wait_for_summaries(proc, count: int, timeout: float = 30.0) -> list[dict]:
    deadline = time.monotonic() + timeout
    while len(found := summaries(proc)) < count:
        assert time.monotonic() < deadline and proc.alive(), proc.output()[-3000:]
        time.sleep(0.05)
    return found


@pytest.fixture
def spawner(tmp_path):
    s = Spawner(tmp_path, fresh_domain_id())
    yield s
    s.reap_all()


# ------------------------------------------------------------------------ no processes
def test_entities_are_agents_resources_and_caches_in_the_map_frame_and_filter_as_the_standard_says():
    world = World(generate_scenario(WorldConfig(height=SIZE, width=SIZE, n_agents=AGENTS), 0))
    frame = MetricFrame(SIZE, SIZE, cell_size=0.5, origin_x=10.0, origin_y=-4.0)
    entities = world_entities(world, frame)
    names = [e.name for e in entities]
    n_resources = len(world.resource_pos)
    assert names == ([f"agent_{a}" for a in range(AGENTS)] + [f"resource_{i}" for i in range(n_resources)]
                     + ["nest_cache_nw", "nest_cache_ne", "nest_cache_sw", "nest_cache_se"])
    for a, entity in enumerate(entities[:AGENTS]):
        assert frame.cell_at(entity.x, entity.y) == tuple(world.pos[a])
    nw = entities[names.index("nest_cache_nw")]
    assert (nw.x, nw.y) == frame.cell_centre(SIZE // 2 - 1, SIZE // 2 - 1)

    def chosen(**filters) -> list[str]:
        return [e.name for e in select(entities, EntityFilters(**filters), frame.cell_size)]

    assert chosen() == names
    assert chosen(filter="^agent_[0-3]$") == ["agent_0", "agent_1", "agent_2", "agent_3"]
    assert chosen(categories=[EntityCategory(category=EntityCategory.CATEGORY_ROBOT)]) == names[:AGENTS]
    assert chosen(tags=TagsFilter(tags=["nest", "cache"], filter_mode=TagsFilter.FILTER_MODE_ALL)) == names[-4:]
    assert chosen(tags=TagsFilter(tags=["nest", "resource"])) == names[AGENTS:]  # FILTER_MODE_ANY
    x, y = nw.x, nw.y
    sphere = Bounds(type=Bounds.TYPE_SPHERE, points=[Vector3(x=x, y=y), Vector3(x=0.1)])
    assert chosen(bounds=sphere, tags=TagsFilter(tags=["nest"])) == ["nest_cache_nw"]
    box = Bounds(type=Bounds.TYPE_BOX, points=[Vector3(x=x + 0.5, y=y + 0.5, z=1.0), Vector3(x=x - 0.5, y=y - 0.5)])
    assert chosen(bounds=box, tags=TagsFilter(tags=["nest"])) == ["nest_cache_nw", "nest_cache_ne", "nest_cache_sw",
                                                                   "nest_cache_se"]  # 0.5 m cells: all four touch it
    for bad, code in ((dict(filter="agent_("), FAILED),
                      (dict(bounds=Bounds(type=Bounds.TYPE_CONVEX_HULL, points=[Vector3()] * 3)),
                       Result.RESULT_FEATURE_UNSUPPORTED)):
        with pytest.raises(FilterError) as error:
            chosen(**bad)
        assert error.value.code == code


def test_settings_map_to_parameter_values_by_one_rule():
    assert [parameter_value(v) for v in (True, 3, 0.5, "x", None)] == [True, 3, 0.5, "x", None]
    assert parameter_value((0, 1)) == "[0, 1]" and parameter_value(((20, 96),)) == "[[20, 96]]"
    assert parameter_value(WorldConfig().rewards).startswith('{"blocked": ')


def assert_step_feedback(feedback: list[tuple[int, int]], steps: int) -> None:
    """SimulateSteps feedback, one per step, as far as it arrives: action feedback is a topic
    that a new client's reader may match late, and rclpy's client drops feedback that comes
    after the result (both seen on 2 busy cores). What arrives is in order and counts right."""
    completed = [k for k, _ in feedback]
    assert completed == sorted(set(completed)) and set(completed) <= set(range(1, steps + 1)), feedback
    assert all(remaining == steps - k for k, remaining in feedback), feedback


# ----------------------------------------------------------------------- processes
def test_a_paused_world_steps_by_service_and_action_resets_with_a_seed_and_matches_formic_sim(spawner, monkeypatch):
    frame = MetricFrame(SIZE, SIZE)
    world = spawner.formic("world", "world", *WORLD, "--seed", "0", "--paused", "--json", limit_s=120)
    spawner.formic("agents", "agents", "--ids", f"0-{AGENTS - 1}", "--policy", "random", "--name", "host",
                   limit_s=120)
    with standard_client(spawner.domain_id, monkeypatch) as client:
        features = client.call(GetSimulatorFeatures, "/formic/get_simulator_features").features
        assert set(features.features) == {
            SimulatorFeatures.ENTITY_TAGS, SimulatorFeatures.ENTITY_BOUNDS_BOX, SimulatorFeatures.ENTITY_CATEGORIES,
            SimulatorFeatures.ENTITY_STATE_GETTING, SimulatorFeatures.ENTITY_INFO_GETTING,
            SimulatorFeatures.SIMULATION_RESET, SimulatorFeatures.SIMULATION_STATE_GETTING,
            SimulatorFeatures.SIMULATION_STATE_SETTING, SimulatorFeatures.SIMULATION_STATE_PAUSE,
            SimulatorFeatures.STEP_SIMULATION_SINGLE, SimulatorFeatures.STEP_SIMULATION_MULTIPLE,
            SimulatorFeatures.STEP_SIMULATION_ACTION}
        assert client.state() == PAUSED
        initial = generate_scenario(WorldConfig(height=SIZE, width=SIZE, n_agents=AGENTS, episode_steps=STEPS), 0)
        assert client.agent_cells(frame).tolist() == [[a.row, a.col] for a in initial.agents]

        # seed 0: 3 single steps and one of 7 by service (step 0 waits for the host), 20 by the action
        assert [client.step(1).result for _ in range(3)] == [OK] * 3
        assert client.step(7).result == OK
        time.sleep(1.0)  # held paused: not stepping time
        assert client.set_state(PAUSED).result == SetSimulationState.Response.ALREADY_IN_TARGET_STATE
        too_many = client.step(STEPS)
        assert too_many.result == FAILED and "20 steps left" in too_many.error_message
        outcome, feedback = client.simulate(20)
        assert outcome.result == OK
        assert_step_feedback(feedback, 20)
        (first,) = wait_for_summaries(world, 1)
        expected = sim_world(0)
        assert first["state_digest"] == expected.state_digest() and first["missed_actions"] == 0
        assert first["rejected_actions"] == {}
        stepping_s = (STEPS - 1) / first["steps_per_s"]
        assert first["paused_s"] >= 1.0
        assert first["wall_s"] - first["startup_s"] == pytest.approx(stepping_s + first["paused_s"], abs=1e-6)
        assert client.agent_cells(frame).tolist() == expected.pos.tolist()
        assert client.step(1).result == FAILED  # the episode is over, the world stays paused
        assert client.state() == PAUSED

        # the world's settings as parameters; the seed of the next reset is writable, the rest read-only
        parameters = client.parameters("/formic/world")
        assert parameters["seed"].integer_value == 0 and parameters["world.height"].integer_value == SIZE
        assert parameters["deadline_s"].double_value == 1.0 and parameters["paused"].bool_value
        assert parameters["rate_hz"].type == ParameterType.PARAMETER_NOT_SET
        refused = client.set_parameter("/formic/world", "deadline_s",
                                       ParameterValue(type=ParameterType.PARAMETER_DOUBLE, double_value=2.0))
        assert not refused.successful and "read-only" in refused.reason
        seed = ParameterValue(type=ParameterType.PARAMETER_INTEGER, integer_value=5)
        assert client.set_parameter("/formic/world", "seed", seed).successful
        host = client.parameters("/formic/host")
        assert host["agent_ids"].string_value == str(list(range(AGENTS))) and host["policy"].string_value == "random"

        # reset: seed 5's episode, exactly as a fresh `formic world --seed 5`; played this time
        assert client.call(ResetSimulation, "/formic/reset_simulation").result.result == OK
        fresh = generate_scenario(WorldConfig(height=SIZE, width=SIZE, n_agents=AGENTS, episode_steps=STEPS), 5)
        assert client.agent_cells(frame).tolist() == [[a.row, a.col] for a in fresh.agents]
        assert client.set_state(PLAYING).result == OK
        second = wait_for_summaries(world, 2)[1]
        assert second["state_digest"] == sim_world(5).state_digest() and second["seed"] == 5
        assert client.state() == PAUSED
        info = client.call(GetEntityInfo, "/formic/get_entity_info", GetEntityInfo.Request(entity="agent_3")).info
        assert info.category.category == EntityCategory.CATEGORY_ROBOT and info.tags == ["agent"]
        missing = client.call(GetEntityState, "/formic/get_entity_state", GetEntityState.Request(entity="agent_99"))
        assert missing.result.result == Result.RESULT_NOT_FOUND
        unsupported = client.call(ResetSimulation, "/formic/reset_simulation",
                                  ResetSimulation.Request(scope=ResetSimulation.Request.SCOPE_SPAWNED))
        assert unsupported.result.result == Result.RESULT_FEATURE_UNSUPPORTED
        names = client.call(GetEntities, "/formic/get_entities",
                            GetEntities.Request(filters=EntityFilters(filter="^nest_"))).entities
        assert len(names) == 4

        assert client.set_state(SimulationState.STATE_QUITTING).result == OK
    assert world.wait(timeout=20) == 0, world.output()[-3000:]


def test_the_planner_follows_a_reset_of_the_same_scenario_and_the_episode_matches_formic_sim(spawner, monkeypatch):
    world = spawner.formic("world", "world", *WORLD, "--seed", "0", "--paused", "--json", limit_s=90)
    planner = spawner.formic("planner", "planner", limit_s=90)
    with standard_client(spawner.domain_id, monkeypatch) as client:
        assert client.step(12).result == OK
        assert client.call(ResetSimulation, "/formic/reset_simulation").result.result == OK  # seed 0 again
        outcome, feedback = client.simulate(STEPS)
        assert outcome.result == OK
        assert_step_feedback(feedback, STEPS)
        (summary,) = wait_for_summaries(world, 1)
        scenario = generate_scenario(WorldConfig(height=SIZE, width=SIZE, n_agents=AGENTS, episode_steps=STEPS), 0)
        assert summary["state_digest"] == run_episode(scenario, "planner").world.state_digest()
        assert summary["missed_actions"] == 0  # (its answer for step 12 may arrive after the reset: rejected)
        assert "differs" not in planner.output()
        assert client.set_state(SimulationState.STATE_QUITTING).result == OK
    assert world.wait(timeout=20) == 0, world.output()[-3000:]


def test_the_docs_client_example_drives_a_paused_world(spawner, tmp_path):
    text = (ROOT / "docs" / "ros.md").read_text()
    match = re.search(r"<!-- docs-test: sim-client -->\n```python\n(.*?)```", text, re.S)
    assert match, "docs/ros.md lost its simulation_interfaces client"
    program = tmp_path / "sim_client.py"
    program.write_text(match.group(1))
    world = spawner.formic("world", "world", *WORLD, "--paused", limit_s=90)
    spawner.formic("agents", "agents", "--ids", f"0-{AGENTS - 1}", "--policy", "random", limit_s=90)
    client = spawner.python("client", str(program), limit_s=90)
    assert client.wait() == 0, client.output()[-3000:]
    assert world.wait(timeout=20) == 0, world.output()[-3000:]  # the example sets STATE_QUITTING
    out = client.output()
    assert "stepped 1" in out and "action ok: True" in out and "quit: True" in out
    assert re.search(r"agent_7: \(\d+\.\d, \d+\.\d\) m in frame map", out)


def test_every_node_lists_its_settings_through_the_standard_parameter_services(spawner, tmp_path, monkeypatch):
    spawner.formic("planner", "planner", limit_s=90)
    spawner.formic("record", "record", "--out", str(tmp_path / "rec"), limit_s=90)
    spawner.formic("trainer", "trainer", "--preset", "cpu", "--run-dir", str(tmp_path / "run"), limit_s=90)
    with standard_client(spawner.domain_id, monkeypatch) as client:
        planner = client.parameters("/formic/planner")
        assert planner["policy"].string_value == "planner" and planner["resend_s"].double_value > 0
        recorder = client.parameters("/formic/recorder")
        assert recorder["out"].string_value == str(tmp_path / "rec") and recorder["namespace"].string_value == "/formic"
        trainer = client.parameters("/formic/trainer")
        assert trainer["preset"].string_value == "cpu" and trainer["max_lag"].integer_value == 4
        assert trainer["run_dir"].string_value == str(tmp_path / "run")
        refused = client.set_parameter("/formic/trainer", "lr",
                                       ParameterValue(type=ParameterType.PARAMETER_DOUBLE, double_value=1.0))
        assert not refused.successful
