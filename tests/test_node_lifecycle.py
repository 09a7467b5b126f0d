"""How node processes start, wait and end: a world nobody joins, a ``--once`` host whose world
leaves, SIGTERM in every state of every node command, and a host that acts for the agents
heard when one observation is late. Real processes, bounded and reaped."""

from __future__ import annotations

import signal
import time

import pytest

pytest.importorskip("rclpy")
pytest.importorskip("formic_interfaces.msg")

from ros_helpers import Spawner, fresh_domain_id  # noqa: E402

SMALL = ("--agents", "2", "--size", "16", "--seed", "0")
SIGTERM_EXIT_S = 5.0  # "within a few seconds"
UP = {"world": "episode:", "agents": "up: agents", "batched": "up: agents", "planner": "up: waiting",
      "record": "recording to", "trainer": "waiting for rollouts"}  # what each node says once it waits


@pytest.fixture
def spawner(tmp_path):
    spawner = Spawner(tmp_path, fresh_domain_id())
    yield spawner
    spawner.reap_all()


def domain(spawner: Spawner) -> tuple[str, str]:
    return "--domain-id", str(spawner.domain_id)


def test_a_world_nobody_joins_exits_with_an_error_unless_asked_to_run_empty(spawner):
    alone = spawner.formic("alone", "world", *SMALL, "--steps", "5", "--startup-timeout", "1.5", *domain(spawner))
    assert alone.wait() == 1
    assert "no agent answered step 0 within 1.5 s" in alone.output() and "--allow-empty" in alone.output()
    empty = spawner.formic("empty", "world", *SMALL, "--steps", "5", "--startup-timeout", "1.5", "--allow-empty",
                           "--json", *domain(spawner))
    assert empty.wait() == 0, empty.output()[-2000:]
    assert empty.json_line()["missed_actions"] == 2 * 5


def test_a_once_host_whose_world_leaves_mid_episode_exits_non_zero(spawner):
    world = spawner.formic("world", "world", *SMALL, "--steps", "100000", "--rate", "20", *domain(spawner))
    host = spawner.formic("host", "agents", "--ids", "0-1", "--policy", "random", "--once", *domain(spawner))
    world.wait_for_text("every agent answered step 0", timeout=60)
    time.sleep(1.0)
    world.popen.send_signal(signal.SIGTERM)
    assert world.wait(timeout=SIGTERM_EXIT_S) == 130
    assert host.wait(timeout=10) == 1, host.output()[-2000:]
    assert "the world left at step" in host.output() and "before the episode ended" in host.output()


def test_a_second_world_in_the_same_namespace_and_domain_is_refused_and_the_first_goes_on(spawner):
    """Two worlds on one domain and namespace would answer each other's agents: the second
    (`formic world` or a whole `formic run`) stops at once, before any agent host starts; another
    namespace is free, and a SIGKILLed world's place is free at once (no 20 s DDS lease)."""
    first = spawner.formic("first", "world", *SMALL, "--steps", "5", "--startup-timeout", "600", *domain(spawner))
    first.wait_for_text("episode:", timeout=60)
    refusal = f"another world already serves namespace /formic on ROS domain {spawner.domain_id} on this machine " \
              f"(process {first.pid})"
    second = spawner.formic("second", "world", *SMALL, "--steps", "5", *domain(spawner))
    assert second.wait(timeout=30) == 1
    assert refusal in second.output(), second.output()[-2000:]
    run = spawner.formic("run", "run", *SMALL, "--steps", "5", "--policy", "random", *domain(spawner))
    assert run.wait(timeout=30) != 0
    assert refusal in run.output() and "up: agents" not in run.output(), run.output()[-2000:]
    elsewhere = spawner.formic("elsewhere", "world", *SMALL, "--steps", "3", "--namespace", "/other",
                               "--startup-timeout", "1", "--allow-empty", "--json", *domain(spawner))
    assert elsewhere.wait(timeout=30) == 0, elsewhere.output()[-2000:]
    assert first.alive() and "every agent answered" not in first.output()
    first.popen.send_signal(signal.SIGKILL)
    first.wait(timeout=5)
    after = spawner.formic("after", "world", *SMALL, "--steps", "3", "--startup-timeout", "1", "--allow-empty",
                           "--json", *domain(spawner))
    assert after.wait(timeout=30) == 0, after.output()[-2000:]
    assert after.json_line()["missed_actions"] == 2 * 3


@pytest.mark.parametrize("state", ["waiting", "stepping"])
def test_every_node_command_exits_soon_after_sigterm(spawner, tmp_path, state):
    """waiting: each command alone in a domain of its own (the world for its agents, the rest
    for a world); stepping: all but the planner (it would claim the hosts' agents) in one
    free-running episode."""
    commands = {
        "world": ("world", *SMALL, "--steps", "100000", "--rate", "50", "--startup-timeout", "600"),
        "agents": ("agents", "--ids", "0", "--policy", "csaf11"),
        "batched": ("agents", "--ids", "1", "--policy", "random", "--transport", "batched"),
        "planner": ("planner",),
        "record": ("record", "--out", str(tmp_path / "rec")),
        "trainer": ("trainer", "--set", "teams=2", "--run-dir", str(tmp_path / "run")),
    }
    if state == "waiting":
        procs = {name: spawner.formic(name, *args, "--domain-id", str(fresh_domain_id()))
                 for name, args in commands.items()}
    else:
        procs = {name: spawner.formic(name, *args, *domain(spawner))
                 for name, args in commands.items() if name != "planner"}
        procs["world"].wait_for_text("every agent answered step 0", timeout=60)
    for name, proc in procs.items():  # each is up, waiting or stepping
        proc.wait_for_text(UP[name], timeout=60)
    time.sleep(0.5)
    for name, proc in procs.items():
        assert proc.alive(), f"{name} ended early:\n{proc.output()[-2000:]}"
        proc.popen.send_signal(signal.SIGTERM)
    stopped = time.monotonic()
    for name, proc in procs.items():
        status = proc.wait(timeout=max(0.1, stopped + SIGTERM_EXIT_S - time.monotonic()))
        assert status in (0, 130), f"{name} exited {status}:\n{proc.output()[-2000:]}"
        assert "Traceback" not in proc.output(), f"{name}:\n{proc.output()[-2000:]}"


PARTIAL = """
import json, sys, time
import numpy as np, rclpy
from formic_agent.policy import AgentBatch
from formic_interfaces.msg import AgentAction, AgentObservation
from formic_ros import convert, qos
import formic_topics as topics
from formic_ros.drivers.agent_host import PARTIAL_WAIT_S, AgentHost
from formic_ros.env import ros_session
from formic_ros.world.ownership import Ownership
from formic_world import World, WorldConfig, generate_scenario

with ros_session(int(sys.argv[1])) as executor:
    scenario = generate_scenario(WorldConfig(height=16, width=16, n_agents=4), seed=5)
    world = World(scenario)
    result = world.reset(scenario)
    node = rclpy.create_node("world", namespace="/formic")  # the world's side of the exchange, by hand
    ownership = Ownership(node, lambda msg, topic: None,
                          lambda kind, topic, profile, callback: node.create_subscription(kind, topic, callback, profile))
    node.create_publisher(type(convert.encode_scenario(scenario, "")), topics.SCENARIO, qos.LATCHED).publish(
        convert.encode_scenario(scenario, "random"))
    obs_pubs = [node.create_publisher(AgentObservation, topics.agent_topic(a, topics.AGENT_OBSERVATION), qos.STREAM)
                for a in range(4)]
    heard = []  # (seconds since step 0 went out, agent, action)
    for a in range(4):
        node.create_subscription(AgentAction, topics.agent_topic(a, topics.AGENT_ACTION),
                                 lambda m: heard.append((time.monotonic() - sent, m.agent_id, m.action)), qos.STREAM)
    host = AgentHost([0, 1, 2, 3], "random")
    for n in [node, *host.nodes]:
        executor.add_node(n)
    def spin(seconds):  # the host's loop (it takes its observations itself), which also runs the world's events
        end = time.monotonic() + seconds
        while time.monotonic() < end:
            host.spin_once(executor, 0.01)
    deadline = time.monotonic() + 30
    while not (host.claim.ready() and all(p.get_subscription_count() for p in obs_pubs)):
        assert time.monotonic() < deadline, "host never ready"
        spin(0.05)
    batch = AgentBatch.from_world(world, observations=result.observations, action_mask=result.action_mask)
    msgs = convert.encode_agent_observations(batch, result.rewards, result.done)
    sent = time.monotonic()
    for a in (0, 1, 2):  # agent 3's observation is "lost" for a while
        obs_pubs[a].publish(msgs[a])
    spin(1.0)
    late_at = time.monotonic() - sent
    obs_pubs[3].publish(msgs[3])
    spin(1.0)
    from formic_runtime.team import Team
    team = Team.for_agents("random", [0, 1, 2, 3]).build()
    team.reset(4, scenario.seed)
    print(json.dumps({"heard": heard, "late_at": late_at, "wait": PARTIAL_WAIT_S,
                      "together": team.act(batch).tolist()}), flush=True)
"""


def test_a_host_acts_for_the_agents_heard_when_one_observation_is_late(spawner):
    """Agents 0-2's step-0 observations arrive, agent 3's a second later: the host answers 0-2
    about PARTIAL_WAIT_S after the first, and 3 when it comes, with the actions it would have
    chosen for all four at once (randomness is drawn per agent and step)."""
    proc = spawner.python("partial", "-c", PARTIAL, str(spawner.domain_id), limit_s=90)
    assert proc.wait() == 0, proc.output()[-3000:]
    out = proc.json_line()
    heard = {agent: (at, action) for at, agent, action in out["heard"]}
    assert sorted(heard) == [0, 1, 2, 3] and len(out["heard"]) == 4  # each answered once
    assert all(out["wait"] * 0.9 <= heard[a][0] < out["late_at"] for a in (0, 1, 2))
    assert heard[3][0] >= out["late_at"]
    assert [heard[a][1] for a in range(4)] == out["together"]


def test_stale_shared_memory_is_removed_and_live_memory_kept(tmp_path):
    """A segment whose lock file nobody holds (its process was SIGKILLed) goes with its lock;
    one whose lock is held, and one too young to judge, stay."""
    import fcntl
    import os

    from formic_ros.launch.processes import SHM_MIN_AGE_S, remove_stale_shm

    old = time.time() - SHM_MIN_AGE_S - 1
    for name in ("fastrtps_00000000000000aa", "fastrtps_00000000000000bb", "fastrtps_00000000000000cc"):
        for path in (tmp_path / name, tmp_path / f"{name}_el"):
            path.write_bytes(b"x")
            if "cc" not in name:
                os.utime(path, (old, old))
    with open(tmp_path / "fastrtps_00000000000000bb_el", "ab") as held:
        fcntl.flock(held, fcntl.LOCK_EX)  # a live owner
        assert remove_stale_shm(tmp_path) == 1
    assert sorted(p.name for p in tmp_path.iterdir()) == [
        "fastrtps_00000000000000bb", "fastrtps_00000000000000bb_el",
        "fastrtps_00000000000000cc", "fastrtps_00000000000000cc_el"]


def test_ctrl_c_during_a_child_wait_leaves_the_child_reapable():
    """A launcher interrupted while it waits for a child must still stop and reap it (Popen's
    own wait could leave its lock held and block the final reap forever)."""
    import os
    import subprocess
    import threading

    from formic_ros.launch.processes import Child
    from formic_runtime.signals import handling

    child = Child("sleeper", subprocess.Popen(["sleep", "30"], start_new_session=True))
    # Python's own Ctrl-C handler: a suite started in the background (`cmd &`) inherits SIGINT
    # ignored, and Python then installs none
    with handling((signal.SIGINT,), signal.default_int_handler):
        for _ in range(20):  # interrupts landing at different moments of the wait loop
            threading.Timer(0.01, os.kill, (os.getpid(), signal.SIGINT)).start()
            with pytest.raises(KeyboardInterrupt):
                child.wait(5.0)
            assert child.alive
    os.killpg(child.process.pid, signal.SIGKILL)
    assert child.poll(block=True) == -signal.SIGKILL
    assert not child.alive and child.process.poll() == -signal.SIGKILL


LEAVING = """
import atexit, os, signal, sys, time
from formic_ros.launch.node_process import leaving
signal.signal(signal.SIGINT, signal.default_int_handler)  # Python's own, as after a node's block
if sys.argv[1] == "leaving":
    leaving()
def late_stop():  # the launcher's stop, reaching a child that is already on its way out
    os.kill(os.getpid(), signal.SIGINT)
    os.kill(os.getpid(), signal.SIGTERM)
    time.sleep(0.2)
atexit.register(late_stop)
"""


@pytest.mark.parametrize("how", ["leaving", "not leaving"])
def test_a_node_process_on_its_way_out_ignores_a_late_stop(how):
    """The launcher stops every child when one fails; a child already leaving then exits as it
    would have (status 0, nothing printed), not with a KeyboardInterrupt traceback at exit."""
    import subprocess
    import sys

    done = subprocess.run([sys.executable, "-c", LEAVING, how], capture_output=True, text=True, timeout=60)
    if how == "leaving":
        assert (done.returncode, done.stderr) == (0, "")
    else:  # the failure the fix removes, shown by the same program
        assert "Traceback" in done.stderr and "KeyboardInterrupt" in done.stderr


LAST_S = "2.0"  # the writer's bound (deliver_last_messages' timeout_s)
WRITER = """
import sys, time
from std_msgs.msg import String
from formic_ros.env import deliver_last_messages, ros_session
with ros_session() as executor:
    import rclpy
    node = rclpy.create_node("last_words_writer")
    executor.add_node(node)
    publisher = node.create_publisher(String, "last_words", 10)
    while publisher.get_subscription_count() == 0:
        executor.spin_once(timeout_sec=0.05)
    print("matched", flush=True)
    sys.stdin.readline()  # the test stops (or not) the reader, then says go
    publisher.publish(String(data="bye"))
    started = time.monotonic()
    deliver_last_messages([node], timeout_s=float(sys.argv[1]))
    print(f"waited {time.monotonic() - started:.3f}", flush=True)
"""
READER = """
import rclpy
from std_msgs.msg import String
from formic_ros.env import ros_session
with ros_session() as executor:
    node = rclpy.create_node("last_words_reader")
    node.create_subscription(String, "last_words", lambda m: print("got", m.data, flush=True), 10)
    executor.add_node(node)
    while True:
        executor.spin_once(timeout_sec=0.1)
"""


@pytest.mark.parametrize("stopped_s", [1.2, None])
def test_a_leaving_process_waits_for_its_last_messages_to_be_acknowledged_but_not_for_long(spawner, stopped_s):
    """A writer gone before a reader took its last sample cannot repair it (a recording once lost
    a robot's last status so): leaving, a process waits until its readers acknowledged, at most
    ``timeout_s`` (2 s here). A reader stopped for 1.2 s still gets the message (a writer that
    left at once lost it); one that stays stopped holds the writer up for the bound only."""
    import subprocess
    import sys

    reader = spawner.python("reader", "-c", READER, limit_s=60)
    writer = subprocess.Popen(["timeout", "-s", "KILL", "60", sys.executable, "-c", WRITER, LAST_S], env=spawner.env,
                              stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True)  # bounded: reads end
    try:
        assert writer.stdout.readline().strip() == "matched"
        reader.popen.send_signal(signal.SIGSTOP)
        writer.stdin.write("go\n")
        writer.stdin.flush()
        if stopped_s is not None:
            time.sleep(stopped_s)
            reader.popen.send_signal(signal.SIGCONT)
        waited = float(writer.stdout.readline().split()[1])
        assert writer.wait(timeout=20) == 0
        reader.popen.send_signal(signal.SIGCONT)
        if stopped_s is not None:
            reader.wait_for_text("got bye", 10)
            assert stopped_s - 0.05 <= waited < 1.95  # until the reader acknowledged
        else:
            assert 1.95 <= waited < 2.5  # the whole bound, no more
    finally:
        if writer.poll() is None:
            writer.kill()
        writer.wait()
