"""Robots in the team (docs/robots.md): the go-to-cell controller, the unicycle model, the
robot-paced step with its fallback, and (over ROS) a mixed team of simulated agents and
simulated robots whose recording verifies."""

from __future__ import annotations

import math
from collections import Counter

import numpy as np
import pytest

from formic_robots.controller import ControllerSettings, go_to, wrap_angle
from formic_robots.steps import RobotStuck, core_route, erase_loops, next_wave, robot_paced_step
from formic_robots.unicycle import Unicycle, UnicycleLimits
from formic_world import NO_ACTION, World, WorldConfig, generate_scenario
from formic_world.metric_frame import MetricFrame

DT = 0.02


def drive_to(robot: Unicycle, waypoints, tolerance, settings, limits, rng, seconds=10.0):
    """Closed loop: controller -> unicycle; returns (seconds taken or None, commands seen)."""
    waypoint, commands, t = 0, [], 0.0
    while t < seconds:
        command = go_to(robot.x, robot.y, robot.yaw, waypoints, waypoint, tolerance, settings)
        commands.append(command)
        if command.arrived and abs(robot.linear) < 1e-3:
            return t, commands
        waypoint = command.waypoint
        t += DT
        robot.advance(t, DT, (command.linear, command.angular), t, limits, rng)
    return None, commands


# ------------------------------------------------------------------------------ controller
def test_controller_turns_on_the_spot_first_and_respects_its_limits():
    settings = ControllerSettings(max_linear=0.4, max_angular=1.5)
    behind = go_to(0.0, 0.0, 0.0, [(-1.0, 0.0)], 0, 0.05, settings)
    assert behind.linear == 0.0 and abs(behind.angular) == 1.5 and not behind.arrived
    ahead = go_to(0.0, 0.0, 0.0, [(5.0, 0.1)], 0, 0.05, settings)
    assert 0 < ahead.linear <= 0.4 and abs(ahead.angular) <= 1.5
    there = go_to(1.0, 0.0, 2.0, [(1.02, 0.0)], 0, 0.05, settings)
    assert there.arrived and (there.linear, there.angular) == (0.0, 0.0)


def test_controller_passes_waypoints_without_stopping_and_stops_on_the_last():
    settings = ControllerSettings(pass_radius=0.15)
    command = go_to(0.9, 0.0, 0.0, [(1.0, 0.0), (1.0, 1.0)], 0, 0.05, settings)
    assert command.waypoint == 1 and not command.arrived  # the corner counts as passed
    assert wrap_angle(3 * math.pi) == pytest.approx(-math.pi)


@pytest.mark.parametrize("noise", [0.0, 0.1])
def test_controller_drives_a_noisy_unicycle_into_every_neighbour_cell(noise):
    frame = MetricFrame(height=5, width=5, cell_size=0.5)
    limits = UnicycleLimits(max_linear=0.5, max_angular=2.5, noise=noise)
    settings = ControllerSettings(max_linear=0.5, max_angular=2.5)
    rng = np.random.default_rng(3)
    for target in [(1, 2), (2, 3), (3, 2), (2, 1)]:
        robot = Unicycle(*frame.cell_centre(2, 2), yaw=0.0)
        taken, commands = drive_to(robot, [frame.cell_centre(*target)], 0.05, settings, limits, rng)
        assert taken is not None and taken < 3.5, target  # a 0.5 m cell at 0.5 m/s, a half turn included
        assert frame.distance_to_cell(robot.x, robot.y, *target) <= 0.05
        assert all(abs(c.linear) <= 0.5 and abs(c.angular) <= 2.5 for c in commands)


def test_controller_follows_a_two_cell_route_round_a_corner():
    frame = MetricFrame(height=5, width=5, cell_size=0.5)
    robot = Unicycle(*frame.cell_centre(2, 2), yaw=math.pi)
    route = [frame.cell_centre(2, 3), frame.cell_centre(1, 3)]
    taken, _ = drive_to(robot, route, 0.05, ControllerSettings(), UnicycleLimits(), np.random.default_rng(0))
    assert taken is not None and frame.cell_at(robot.x, robot.y) == (1, 3)


# ------------------------------------------------------------------------------ kinematics
def test_unicycle_keeps_its_acceleration_and_speed_limits():
    limits = UnicycleLimits(max_linear=0.5, max_angular=1.0, linear_accel=1.0, angular_accel=2.0, noise=0.0)
    robot, rng = Unicycle(0.0, 0.0, 0.0), np.random.default_rng(0)
    robot.advance(DT, DT, (10.0, 10.0), 0.0, limits, rng)
    assert robot.linear == pytest.approx(1.0 * DT) and robot.angular == pytest.approx(2.0 * DT)
    for k in range(200):
        robot.advance((k + 2) * DT, DT, (10.0, 0.0), (k + 2) * DT, limits, rng)
    assert robot.linear == pytest.approx(0.5) and robot.angular == pytest.approx(0.0)


def test_unicycle_stops_on_a_stale_command_and_while_stalled():
    limits = UnicycleLimits(noise=0.0, command_timeout_s=0.5, linear_accel=100.0)
    robot, rng = Unicycle(0.0, 0.0, 0.0, linear=0.5), np.random.default_rng(0)
    robot.advance(1.0, DT, (0.5, 0.0), 0.0, limits, rng)  # the command is 1 s old: a stop
    assert robot.linear == 0.0
    stalling = UnicycleLimits(noise=0.0, stall_rate=1e9, stall_s=1.0, linear_accel=100.0)
    robot.advance(1.02, DT, (0.5, 0.0), 1.02, stalling, rng)
    assert robot.linear == 0.0 and robot.stalled_until == pytest.approx(2.02)


def test_unicycle_noise_is_seeded():
    limits = UnicycleLimits(noise=0.2)

    def path(seed):
        robot, rng = Unicycle(0.0, 0.0, 0.0), np.random.default_rng(seed)
        for k in range(100):
            robot.advance(k * DT, DT, (0.5, 0.5), k * DT, limits, rng)
        return robot.x, robot.y, robot.yaw

    assert path(1) == path(1) != path(2)


# ------------------------------------------------------------------------ robot-paced step
def test_erase_loops_and_waves():
    assert erase_loops([(0, 0), (0, 1), (0, 0), (1, 0)]) == ((0, 0), (1, 0))
    # robot 1 follows robot 0 into the cell it leaves: it waits for the next wave
    routes = {0: ((0, 2),), 1: ((0, 1),), 2: ((5, 5),)}
    at = {0: (0, 1), 1: (0, 0), 2: (5, 5)}
    assert next_wave(routes, at, {0, 1, 2}) == [0, 2]
    assert next_wave(routes, {**at, 0: (0, 2)}, {1}) == [1]


def random_actions(world: World, rng: np.random.Generator) -> np.ndarray:
    """A valid action for each agent; JOIN whenever it is valid (busy queues, as foragers make)."""
    mask = world.action_mask()
    return np.array([4 if m[4] else rng.choice(np.flatnonzero(m)) if m.any() else 0 for m in mask], dtype=np.int64)


class FakeRobots:
    """Robots that fail a move with probability ``p``; checks that no robot ever drives into a
    cell another robot stands in, and tracks where each robot really is."""

    def __init__(self, world: World, robots, p: float, seed: int):
        self.cell = {r: (int(world.pos[r, 0]), int(world.pos[r, 1])) for r in robots}
        self.rng = np.random.default_rng(seed)
        self.p = p
        self.calls = []

    def __call__(self, attempt: int, routes: dict) -> dict:
        self.calls.append((attempt, routes))
        entered = {}
        for r, route in routes.items():
            previous = self.cell[r]
            for cell in route:
                assert abs(cell[0] - previous[0]) + abs(cell[1] - previous[1]) <= 1, (r, route)
                previous = cell
            cells = set(route) - {self.cell[r]}
            others = {c for o, c in self.cell.items() if o != r}
            assert not cells & others, f"robot {r} would drive into another robot: {routes}, {self.cell}"
            assert not any(cells & e for e in entered.values()), f"two robots enter one cell: {routes}"
            entered[r] = cells
        outcome = {}
        for r, route in routes.items():
            moving = route[-1] != self.cell[r]
            outcome[r] = not (moving and self.rng.random() < self.p)
            if outcome[r]:
                self.cell[r] = route[-1]
        return outcome


def scenario(seed=5, n=24, size=16, steps=300):
    return generate_scenario(WorldConfig(height=size, width=size, n_agents=n, episode_steps=steps), seed)


@pytest.mark.parametrize("p", [0.0, 0.3])
def test_committed_steps_equal_the_core_stepped_with_the_applied_actions(p):
    """Whatever fails, the committed world is the core's step under the applied actions (so a
    recording of them replays exactly), robots stand where the world says, and failed robots
    did nothing."""
    sc = scenario()
    world, twin = World(sc), World(sc)
    robots = list(range(12))
    fake = FakeRobots(world, robots, p, seed=1)
    rng = np.random.default_rng(7)
    failures = joins = 0
    for _ in range(sc.config.episode_steps):
        actions = random_actions(world, rng)
        queued = world.queued.copy()  # a queued robot's action is ignored: its failure cannot be undone
        report = robot_paced_step(world, actions, robots, fake)
        expected = actions.copy()
        expected[[r for r in report.failed if not queued[r]]] = NO_ACTION
        assert (report.applied == expected).all()
        result = twin.step(report.applied)
        assert world.state_digest() == twin.state_digest()
        assert (report.result.observations == result.observations).all()
        assert all(fake.cell[r] == tuple(world.pos[r]) for r in robots)
        failures += len(report.failed)
        joins += int((world.queued[robots]).sum())
    assert (failures > 20) == (p > 0)
    assert joins > 0  # robots did queue (the queue moves were driven too)


def test_a_failed_robot_does_nothing_and_the_step_is_deterministic():
    sc = scenario(seed=9)
    world = World(sc)
    actions = random_actions(world, np.random.default_rng(0))
    movers = [r for r in range(8) if actions[r] < 4 and world.action_mask()[r, actions[r]]]
    victim = movers[0]

    def fail_victim(attempt, routes):
        return {r: r != victim or routes[r][-1] == (int(world.pos[r, 0]), int(world.pos[r, 1])) for r in routes}

    runs = []
    for _ in range(2):
        w = World(sc)
        start = tuple(w.pos[victim])
        report = robot_paced_step(w, actions, range(8), lambda a, routes: {
            r: r != victim or routes[r][-1] == start for r in routes})
        runs.append((w.state_digest(), report.applied.copy(), len(report.attempts)))
        assert tuple(w.pos[victim]) == start and report.applied[victim] == NO_ACTION
        direct = World(sc)
        fallback = actions.copy()
        fallback[victim] = NO_ACTION
        direct.step(fallback)
        assert w.state_digest() == direct.state_digest()
    assert runs[0][0] == runs[1][0] and (runs[0][1] == runs[1][1]).all() and runs[0][2] == runs[1][2] == 2


def test_a_robot_that_never_arrives_stops_the_world_with_an_error():
    sc = scenario(seed=9)
    world = World(sc)
    with pytest.raises(RobotStuck):
        robot_paced_step(world, np.zeros(sc.config.n_agents, dtype=np.int64), [0], lambda a, routes: {0: False},
                         max_attempts=3)


def test_snapshot_restore_is_exact_across_respawns():
    sc = generate_scenario(WorldConfig(height=16, width=16, n_agents=16, capacity="finite", capacity_min=1,
                                       capacity_max=1, episode_steps=400), 3)
    world, twin = World(sc), World(sc)
    rng = np.random.default_rng(4)
    grid_changes = 0
    for _ in range(400):
        actions = random_actions(world, rng)
        saved = world.snapshot()
        grid = world.grid.copy()
        world.step(random_actions(world, np.random.default_rng(1)))
        grid_changes += not np.array_equal(grid, world.grid)
        world.restore(saved)
        world.step(actions)
        result = twin.step(actions)
        assert world.state_digest() == twin.state_digest()
        assert (world.last_result.observations == result.observations).all()
    assert grid_changes > 0  # some tentative steps respawned a resource


def test_core_route_covers_a_join_and_a_queue_move_in_one_step():
    """JOIN from a neighbour of a queue's entry, then the queue moves up in the same step: two
    cells, through the spot joined at (the only rule that moves an agent more than one cell)."""
    cfg = WorldConfig(height=16, width=16, n_agents=16, episode_steps=3000)
    seen = 0
    for seed in range(6):
        sc = generate_scenario(cfg, seed)
        world, rng = World(sc), np.random.default_rng(seed)
        for _ in range(400):
            before = world.pos.copy()
            world.step(random_actions(world, rng))
            for a in range(cfg.n_agents):
                route = core_route(world, a, tuple(int(v) for v in before[a]))
                seen += len(route) == 2
    assert seen > 0


# ------------------------------------------------------------------------------ live view
def test_robots_are_drawn_at_their_metric_poses_over_the_grid():
    pytest.importorskip("foxglove")
    from foxglove.messages import Timestamp
    from google.protobuf import descriptor_pb2, descriptor_pool, message_factory

    from formic_view.robots import robot_scene

    frame = MetricFrame(height=8, width=8, cell_size=0.5, origin_x=-1.0, origin_y=2.0)
    x, y = frame.cell_centre(2, 5)
    update = robot_scene({7: (x + 0.1, y, math.pi / 2)}, frame, Timestamp(0, 0))
    schema = update.get_schema()  # decoded as a viewer does: with the schema the message names
    pool = descriptor_pool.DescriptorPool()
    for file in descriptor_pb2.FileDescriptorSet.FromString(schema.data).file:
        pool.Add(file)
    scene = message_factory.GetMessageClass(pool.FindMessageTypeByName(schema.name)).FromString(update.encode())
    (entity,) = scene.entities
    position = entity.cylinders[0].pose.position
    # the view draws a cell one unit wide: cell (2, 5) spans x 5-6 and y 5-6 (rows count from the north)
    assert (position.x, position.y) == pytest.approx((5.5 + 0.2, 5.5))
    assert entity.id == "robot_7" and entity.arrows[0].pose.orientation.z == pytest.approx(math.sin(math.pi / 4))


# --------------------------------------------------------------------------- the mixed team
MIXED_SEED = 2800  # a scenario no test or selection uses elsewhere; every robot delivers in sim within 80 steps
MIXED_STEPS = 100
ROBOTS = (28, 29, 30, 31)
TOLERANCE = 0.1


def test_mixed_team_of_simulated_agents_and_simulated_robots_forages_and_its_recording_verifies(tmp_path):
    """28 simulated agents and 4 simulated robots (formic robots-sim behind formic robot's bridges,
    started by `formic run --robots --robots-sim`) on 32x32: the robots deliver food, no two
    agents ever share a cell, every committed step has each robot stopped within the tolerance
    of its cell, robots that stall make moves fail (the world applies NO_ACTION instead), the
    recording verifies, and the live view draws the robots (`--view-wait`: the world waits for this
    test's viewer before step 0, however slowly the machine starts it)."""
    pytest.importorskip("rclpy")
    pytest.importorskip("formic_interfaces.msg")
    from ros_helpers import Spawner, fresh_domain_id
    from test_view import TOPICS as VIEW_TOPICS, FoxgloveClient, _free_port

    from formic_view.robots import ROBOTS_TOPIC

    from formic_record.reading import Recording
    from formic_topics import ROBOT_GOAL, ROBOT_STATUS, STATE, agent_topic, full_name

    spawner = Spawner(tmp_path, fresh_domain_id())
    recording, port = tmp_path / "rec", _free_port()
    try:
        run = spawner.formic(
            "run", "run", "--agents", "32", "--size", "32", "--steps", str(MIXED_STEPS), "--seed", str(MIXED_SEED),
            "--robots", "28-31", "--robots-sim", "--cell-size", "0.5", "--robot-max-speed", "2.0",
            "--robot-max-turn", "8", "--robot-tolerance", str(TOLERANCE), "--robot-cell-s", "2.5",
            "--robot-stall-rate", "0.02",
            "--record", str(recording), "--view", "--view-port", str(port), "--view-wait",
            "--log-dir", str(tmp_path / "logs"), "--timeout", "400", "--json", limit_s=460)
        run.wait_for_text(f"ws://127.0.0.1:{port}", 60)
        scenes, seen = [], Counter()
        with FoxgloveClient(f"ws://127.0.0.1:{port}", timeout_s=60) as client:
            client.await_channels([*VIEW_TOPICS, ROBOTS_TOPIC], timeout_s=120)  # the robots' is advertised last
            client.subscribe_all()
            for topic, _, message in client.messages(lambda topic, m: len(scenes) >= 20, timeout_s=300):
                seen[topic] += 1
                if topic == ROBOTS_TOPIC:
                    scenes.append(message)
        assert run.wait() == 0, run.output()[-3000:]
        summary = run.json_line()
    finally:
        spawner.reap_all()

    delivered = summary["per_agent"]["delivered"]
    assert sum(delivered[r] for r in ROBOTS) > 0, summary["per_agent"]
    assert summary["robots"] == list(ROBOTS) and summary["missed_actions"] == 0
    assert summary["robot_failed_moves"] > 0  # stalls happened, and the world took those moves back

    verify = spawner.formic("verify", "replay", str(recording), "--verify", "--json", limit_s=200)
    assert verify.wait() == 0, verify.output()[-3000:]
    assert verify.json_line()["ok"]

    rec = Recording(recording)
    store = rec.typestore()
    namespace = "/formic"
    wanted = [full_name(namespace, STATE)] + [full_name(namespace, agent_topic(r, leaf))
                                               for r in ROBOTS for leaf in (ROBOT_GOAL, ROBOT_STATUS)]
    states, arrivals = {}, {}
    for message in rec.messages(wanted):
        msg = store.deserialize_cdr(message.data, message.msgtype)
        if message.topic.endswith(STATE):
            states[int(msg.step)] = msg
        elif message.topic.endswith(ROBOT_STATUS) and msg.status == 1:  # ARRIVED: the step's last attempt counts
            key = (int(msg.agent_id), int(msg.step))
            if key not in arrivals or msg.attempt >= arrivals[key].attempt:
                arrivals[key] = msg
    assert sorted(states) == list(range(MIXED_STEPS + 1))
    frame = MetricFrame(32, 32, 0.5)
    for step, state in states.items():
        cells = set(zip(state.agent_rows.tolist(), state.agent_cols.tolist()))
        assert len(cells) == 32, f"two agents share a cell after step {step}"
        if step == 0:
            continue
        for r in ROBOTS:  # the committed step t-1 put robot r where the state says; it stood there
            arrival = arrivals[(r, step - 1)]
            cell = (int(state.agent_rows[r]), int(state.agent_cols[r]))
            assert (arrival.row, arrival.col) == cell, (step, r)
            assert frame.distance_to_cell(arrival.x, arrival.y, *cell) <= TOLERANCE
    assert len(scenes) >= 20, seen
    assert {e.id for e in scenes[-1].entities} == {f"robot_{r}" for r in ROBOTS}
