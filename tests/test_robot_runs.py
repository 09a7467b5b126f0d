"""Robots in `formic run`, as docs/robots.md describes them: a fake robot (docs/robots.md's
program, not `formic robots-sim`) decided for by the user's node (docs/ros.md's robot program),
both as written; a node spoofing a robot's statuses halts it; a driver on the wrong ROS domain
ends the run with one error; a child's error reaches the user in one line. Real processes,
bounded and reaped."""

from __future__ import annotations

import re
import time

import pytest

pytest.importorskip("rclpy")
pytest.importorskip("formic_interfaces.msg")

from ros_helpers import ROOT, Spawner, fresh_domain_id  # noqa: E402

TEAM = ["--agents", "8", "--size", "16", "--seed", "0", "--policy", "csaf11"]


def docs_program(doc: str, marker: str) -> str:
    """The python block after ``<!-- docs-test: MARKER -->`` in ``docs/DOC``, as a user pastes it."""
    match = re.search(rf"<!-- docs-test: {marker} -->\n```python\n(.*?)```", (ROOT / "docs" / doc).read_text(), re.S)
    assert match, f"docs/{doc} lost its {marker} program"
    return match.group(1)


def docs_run_command() -> list[str]:
    """The `formic run` of docs/robots.md's fake-robot block, its arguments as the shell splits them."""
    import shlex

    text = (ROOT / "docs" / "robots.md").read_text()
    line = re.search(r"^(formic run [^&]*--external 5.*?)&$", text.replace("\\\n", ""), re.M | re.S).group(1)
    return shlex.split(line)[2:]


def test_the_docs_fake_robot_decided_by_the_docs_agent_node(tmp_path):
    (tmp_path / "fake_robot.py").write_text(docs_program("robots.md", "fake-robot"))
    (tmp_path / "robot_agent.py").write_text(docs_program("ros.md", "robot-snippet"))
    spawner = Spawner(tmp_path, fresh_domain_id())
    try:
        robot = spawner.python("robot", str(tmp_path / "fake_robot.py"), "5", limit_s=150)
        args = docs_run_command()
        assert args[:args.index("--robots")] == ["--agents", "8", "--size", "16", "--steps", "30", "--seed", "0",
                                                 "--policy", "csaf11"]
        run = spawner.formic("run", "run", *args, "--json", "--domain-id", str(spawner.domain_id), limit_s=150)
        agent = spawner.python("agent", str(tmp_path / "robot_agent.py"), "5", limit_s=150)
        assert run.wait() == 0, run.output()[-3000:]
        assert agent.wait(timeout=30) == 0, agent.output()[-3000:]  # it leaves when the episode ends
        summary = run.json_line()
        assert summary["robots"] == [5] and summary["missed_actions"] == 0 and summary["rejected_actions"] == {}
        assert summary["last_answered_step"][5] == 29 and summary["rejected_statuses"] == {}
        assert summary["robot_step_s_max"] > 0.0  # the robot paced the steps
        assert "agent 5: driven by its node /formic/agent_5" in run.output()
        assert "odometry origin: the start cell's centre" in run.output()
        assert robot.alive()  # the fake robot is the user's: the run leaves it running
    finally:
        spawner.reap_all()


SPOOFER = """
import sys, time, rclpy
from formic_interfaces.msg import RobotStatus
rclpy.init(domain_id=int(sys.argv[1]))
node = rclpy.create_node("spoofer", namespace="/formic")
pub = node.create_publisher(RobotStatus, "agent_2/robot_status", 10)
while not pub.get_subscription_count():
    rclpy.spin_once(node, timeout_sec=0.05)
print("spoofing", flush=True)
end = time.monotonic() + float(sys.argv[2])
while time.monotonic() < end:
    pub.publish(RobotStatus(agent_id=2, step=0, status=RobotStatus.ARRIVED))
    rclpy.spin_once(node, timeout_sec=0.1)
"""


def test_a_second_status_publisher_halts_its_robot_with_one_error(tmp_path):
    """The bridge placed robot 2 (its first publisher); a node that then publishes on the robot's
    status topic halts it for as long as it publishes, with one ERROR naming both."""
    spawner = Spawner(tmp_path, fresh_domain_id())
    try:
        run = spawner.formic("run", "run", *TEAM[:6], "--policy", "random", "--steps", "40", "--robots", "2",
                             "--robots-sim", "--cell-size", "0.5", "--robot-max-speed", "2", "--robot-max-turn", "8",
                             "--robot-cell-s", "1", "--json", "--domain-id", str(spawner.domain_id), limit_s=150)
        run.wait_for_text("every agent answered step 0", timeout=60)
        spoofer = spawner.python("spoofer", "-c", SPOOFER, str(spawner.domain_id), "3", limit_s=60)
        assert run.wait() == 0, run.output()[-3000:]
        assert "spoofing" in spoofer.output()
        summary = run.json_line()
        assert summary["rejected_statuses"].get("foreign publisher", 0) > 0 and summary["robot_failed_moves"] > 0
        errors = [line for line in run.output().splitlines() if "publishers are on /formic/agent_2/robot_status" in line]
        assert len(errors) == 1, run.output()[-3000:]
        assert "robot 2's statuses come from its bridge /formic/robot_bridge_2" in errors[0]
        assert "/formic/spoofer" in errors[0] and "[ERROR]" in errors[0]
    finally:
        spawner.reap_all()


def error_lines(output: str) -> list[str]:
    return [line for line in output.splitlines() if line.startswith("Error:")]


def test_a_driver_on_another_domain_ends_the_run_with_one_error(tmp_path):
    (tmp_path / "robot_agent.py").write_text(docs_program("ros.md", "robot-snippet"))
    spawner = Spawner(tmp_path, fresh_domain_id())
    (tmp_path / "elsewhere").mkdir()
    elsewhere = Spawner(tmp_path / "elsewhere", (spawner.domain_id + 1 - 120) % 100 + 120)
    try:
        elsewhere.python("agent", str(tmp_path / "robot_agent.py"), "3", limit_s=60)
        started = time.monotonic()
        run = spawner.formic("run", "run", *TEAM, "--steps", "50", "--external", "3", "--startup-timeout", "3",
                             "--domain-id", str(spawner.domain_id), limit_s=60)
        assert run.wait() == 1, run.output()[-3000:]
        assert time.monotonic() - started < 30
        (error,) = error_lines(run.output())
        assert error.startswith("Error: world: agents 3 did not answer step 0 within 3 s"), error
        assert "ROS_DOMAIN_ID" in error and "--namespace" in error and "ROS_AUTOMATIC_DISCOVERY_RANGE" in error
        assert "Traceback" not in run.output()
    finally:
        elsewhere.reap_all()
        spawner.reap_all()


def test_a_childs_error_reaches_the_user_in_one_line(tmp_path):
    model = tmp_path / "notes.pt"
    model.write_text("not a checkpoint\n")
    spawner = Spawner(tmp_path, fresh_domain_id())
    try:
        run = spawner.formic("run", "run", "--agents", "4", "--size", "16", "--steps", "5", "--model", str(model),
                             "--domain-id", str(spawner.domain_id), limit_s=90)
        assert run.wait() == 1, run.output()[-3000:]
        (error,) = error_lines(run.output())
        assert error.startswith("Error: host0: ") and "notes.pt" in error, error
        assert "Traceback" not in run.output()
    finally:
        spawner.reap_all()


def test_robots_outside_the_team_are_refused_before_any_process_starts(tmp_path):
    spawner = Spawner(tmp_path, fresh_domain_id())
    try:
        run = spawner.formic("run", "run", *TEAM, "--robots", "99", "--robots-sim", limit_s=30)
        assert run.wait() == 1
        assert run.output().strip() == "Error: --robots 99: not agents of this team of 8 (0-7)"
    finally:
        spawner.reap_all()
