"""Only an agent's owner drives it: the robot program in docs/ros.md drives its --external agent as
written; a spoofing node changes nothing; two nodes claiming one agent, a second node on an owned
agent's topic, or a claim from a node the run did not start give a clear error with the first
owner kept. Real processes, bounded and reaped."""

from __future__ import annotations

import json
import re
import time

import numpy as np
import pytest

pytest.importorskip("rclpy")
pytest.importorskip("formic_interfaces.msg")

from ros_helpers import ROOT, Spawner, fresh_domain_id  # noqa: E402

from formic_runtime.episode import run_episode  # noqa: E402
from formic_runtime.team import Team  # noqa: E402
from formic_world import WorldConfig, generate_scenario  # noqa: E402

WORLD = ["--agents", "8", "--size", "24", "--seed", "0", "--steps", "40", "--deadline-ms", "5000", "--json"]
SPOOFER = """
import sys, time, numpy as np, rclpy
from formic_interfaces.msg import ActionBatch, AgentAction
rclpy.init(domain_id=int(sys.argv[1]))
node = rclpy.create_node("spoofer", namespace="/formic")
pubs = {f"/formic/agent_{a}/action": (node.create_publisher(AgentAction, f"/formic/agent_{a}/action", 10), a)
        for a in range(8)}
pubs["/formic/actions"] = (node.create_publisher(ActionBatch, "/formic/actions", 10), None)
while not all(pub.get_subscription_count() for pub, _ in pubs.values()):
    rclpy.spin_once(node, timeout_sec=0.05)
print("spoofing", flush=True)
end = time.monotonic() + 100
while time.monotonic() < end:
    for step in range(41):
        for pub, agent in pubs.values():
            if agent is None:
                pub.publish(ActionBatch(step=step, agent_ids=np.arange(8, dtype=np.uint32).tobytes(), actions=bytes([4] * 8)))
            else:
                pub.publish(AgentAction(step=step, agent_id=agent, action=4))
    rclpy.spin_once(node, timeout_sec=0.01)
"""


def run_with(tmp_path, name: str, spoof: bool) -> dict:
    spawner = Spawner(tmp_path / name, fresh_domain_id())
    domain = ("--domain-id", str(spawner.domain_id))
    try:
        world = spawner.formic("world", "world", *WORLD, *domain, limit_s=120)
        if spoof:  # it publishes JOIN for every agent, matched with the world before the host is there
            spawner.python("spoofer", "-c", SPOOFER, str(spawner.domain_id), limit_s=120).wait_for_text(
                "spoofing", timeout=60)
        spawner.formic("host", "agents", "--ids", "0-7", "--policy", "csaf11", "--transport", "batched", "--once",
                       *domain, limit_s=120)
        assert world.wait() == 0, world.output()[-3000:]
        return world.json_line()
    finally:
        spawner.reap_all()


def test_a_spoofing_node_changes_nothing(tmp_path):
    (tmp_path / "clean").mkdir()
    (tmp_path / "spoofed").mkdir()
    clean = run_with(tmp_path, "clean", spoof=False)
    spoofed = run_with(tmp_path, "spoofed", spoof=True)
    assert clean["rejected_actions"] == {} and clean["missed_actions"] == 0
    assert (spoofed["food"], spoofed["state_digest"]) == (clean["food"], clean["state_digest"])
    assert spoofed["rejected_actions"].get("not owner", 0) + spoofed["rejected_actions"].get("unclaimed", 0) > 0


def test_two_nodes_claiming_one_agent(tmp_path):
    spawner = Spawner(tmp_path, fresh_domain_id())
    try:
        example = str(ROOT / "examples" / "external_agent.py")
        first = spawner.python("first", example, "--agent", "2", "--domain-id", str(spawner.domain_id), limit_s=120)
        second = spawner.python("second", example, "--agent", "2", "--domain-id", str(spawner.domain_id),
                                limit_s=120)
        for node in (first, second):  # both claims are out (latched) before the world starts
            node.wait_for_text("driving agent 2", timeout=60)
        # Long enough (~5 s) that the world surely hears both claims: a world that starts in 0.6 s and
        # plays 40 steps in 0.2 s had ended before the second claim was discovered (seen under load).
        run = spawner.formic("run", "run", "--agents", "8", "--size", "24", "--seed", "0", "--steps", "1000",
                             "--policy", "random", "--external", "2", "--deadline-ms", "5000", "--json",
                             "--domain-id", str(spawner.domain_id), limit_s=120)
        assert run.wait() == 0, run.output()[-3000:]
        time.sleep(1)  # the refused one idles (it may miss the end): reaped below
        summary = run.json_line()
        assert summary["missed_actions"] == 0 and summary["last_answered_step"] == [999] * 8
        assert "claim refused, first owner kept" in run.output()
        refused = ["is driven by another node" in p.output() for p in (first, second)]
        assert sorted(refused) == [False, True], "exactly one of them was refused"
    finally:
        spawner.reap_all()


class GraphNode:
    """The little of an rclpy node the world's Ownership uses, with a graph the test sets."""

    def __init__(self):
        self.names: list[tuple[str, str]] = []
        self.logged: list[str] = []

    def get_namespace(self):
        return "/formic"

    def get_node_names_and_namespaces(self):
        return self.names

    def get_logger(self):
        node = self

        class Logger:
            def info(self, text):
                node.logged.append(text)

            error = warning = info
        return Logger()

    def create_publisher(self, *args):
        class Publisher:
            def publish(self, msg):
                pass
        return Publisher()

    def create_timer(self, *args):
        return None


def test_a_claim_under_the_first_owners_name_waits_before_it_takes_over(monkeypatch):
    """Two nodes named agent_2: the second's claim arrives late and the graph shows one agent_2
    (the other not discovered yet). It is refused until it is 2 s old; then, if the graph still
    shows one agent_2 (a restart), it takes over; if two, the first owner stays."""
    import json

    from std_msgs.msg import String

    from formic_ros.world import ownership

    for graph_after, owner_after in ((1, "second"), (2, "first")):
        clock = [100.0]
        monkeypatch.setattr(ownership.time, "monotonic", lambda: clock[0])
        node = GraphNode()
        world = ownership.Ownership(node, offer_batch=None, subscribe=lambda *args: None)
        node.names = [("agent_2", "/formic")]
        world._on_claim(String(data=json.dumps({"owner": "/formic/agent_2", "token": "first", "agents": [2]})))
        clock[0] += 3.0  # the first claim is old, the second arrives now
        world._on_claim(String(data=json.dumps({"owner": "/formic/agent_2", "token": "second", "agents": [2]})))
        assert world.owner_of[2] == "first" and "second" in world.refused
        assert any("claim refused, first owner kept" in line for line in node.logged)
        clock[0] += 2.5
        node.names = [("agent_2", "/formic")] * graph_after
        world._recheck()
        assert world.owner_of[2] == owner_after


# ------------------------------------------------------------------ the robot program of docs/ros.md
def readme_robot_program() -> str:
    """docs/ros.md's robot node, exactly as a user pastes it (the block after its marker)."""
    text = (ROOT / "docs" / "ros.md").read_text()
    match = re.search(r"<!-- docs-test: robot-snippet -->\n```python\n(.*?)```", text, re.S)
    assert match, "docs/ros.md lost its robot program"
    return match.group(1)


def action_steps_in(recording, topic: str) -> list[int]:
    """The steps of every message on ``topic`` in a recording (read with mcap_ros2, as a user would)."""
    from mcap.reader import make_reader
    from mcap_ros2.decoder import DecoderFactory

    (mcap,) = recording.glob("*.mcap")
    with open(mcap, "rb") as f:
        reader = make_reader(f, decoder_factories=[DecoderFactory()])
        return [msg.step for _, _, _, msg in reader.iter_decoded_messages(topics=[topic])]


def test_the_readme_robot_program_drives_its_external_agent(tmp_path):
    program = tmp_path / "robot_agent.py"
    program.write_text(readme_robot_program())
    spawner = Spawner(tmp_path, fresh_domain_id())
    recording = tmp_path / "rec"
    try:
        robot = spawner.python("robot", str(program), "3", limit_s=150)
        run = spawner.formic("run", "run", "--agents", "16", "--size", "32", "--steps", "300", "--policy", "csaf11",
                             "--external", "3", "--record", str(recording), "--json",
                             "--domain-id", str(spawner.domain_id), limit_s=150)
        assert run.wait() == 0, run.output()[-3000:]
        assert robot.wait(timeout=30) == 0, robot.output()[-3000:]  # it leaves when the episode ends
        summary = run.json_line()
        assert summary["missed_actions"] == 0 and summary["rejected_actions"] == {}
        assert summary["last_answered_step"] == [299] * 16
        assert "agent 3: driven by its node /formic/agent_3" in run.output()
        assert set(action_steps_in(recording, "/formic/agent_3/action")) == set(range(300))  # step 0 maybe twice
        verify = spawner.formic("verify", "replay", str(recording), "--verify", limit_s=120)
        assert verify.wait() == 0, verify.output()[-3000:]
    finally:
        spawner.reap_all()


def sim_digest(steps: int, team: str | Team = "csaf11") -> tuple[float, str]:
    scenario = generate_scenario(WorldConfig(height=24, width=24, n_agents=8, episode_steps=steps), 0)
    result = run_episode(scenario, team)
    return result.food, result.world.state_digest()


def test_a_node_beside_the_host_halts_its_agent_instead_of_hijacking_it(tmp_path):
    """The robot program without --external: two nodes are /formic/agent_3. From the moment the
    world's reader matches the second one it applies neither node's actions; with a deadline
    long enough to outlast the stray node, agent 3 waits and then goes on with the host, so the
    run is exactly `formic sim`'s: no action of the stray node was ever applied."""
    program = tmp_path / "robot_agent.py"
    program.write_text(readme_robot_program())
    spawner = Spawner(tmp_path, fresh_domain_id())
    try:
        stray = spawner.python("stray", str(program), "3", limit_s=120)
        run = spawner.formic("run", "run", *WORLD[:6], "--steps", "300", "--policy", "csaf11", "--deadline-ms", "30000",
                             "--json", "--domain-id", str(spawner.domain_id), limit_s=120)
        run.wait_for_text("publishers are on /formic/agent_3/action", timeout=60)
        stray.kill()  # gone from the graph within the loopback lease (5 s)
        assert run.wait() == 0, run.output()[-3000:]
        summary = run.json_line()
        assert (summary["food"], summary["state_digest"]) == sim_digest(300)
        assert summary["rejected_actions"].get("foreign publisher", 0) > 0 and summary["missed_actions"] == 0
        error = next(line for line in run.output().splitlines() if "publishers are on /formic/agent_3/action" in line)
        assert "agent 3 is driven by /formic/agent_host_0, but 2 publishers" in error
    finally:
        spawner.reap_all()


OUTSIDER = """
import sys, rclpy
from formic_ros.drivers.claim import Claim
rclpy.init(domain_id=int(sys.argv[1]))
node = rclpy.create_node("early_bird", namespace="/formic")
claim = Claim(node, range(8))
print("claimed", flush=True)
while claim.why_refused is None:
    rclpy.spin_once(node, timeout_sec=0.1)
print("refused:", claim.why_refused, flush=True)
"""


def test_a_claim_from_a_node_the_run_did_not_start_is_refused(tmp_path):
    """A node that claims the whole team before the run's host starts does not take it, and is
    told why. Agent 7 is --external and its host starts only once the outsider has heard the
    refusal: the world waits at step 0 for it, so the refusal reaches the outsider while the world
    lives however slow discovery is (CI once ended a 400-step run before it did)."""
    spawner = Spawner(tmp_path, fresh_domain_id())
    try:
        outsider = spawner.python("outsider", "-c", OUTSIDER, str(spawner.domain_id), limit_s=120)
        outsider.wait_for_text("claimed", timeout=60)
        world = [*WORLD[:WORLD.index("--steps") + 1], "400", "--deadline-ms", "5000"]
        run = spawner.formic("run", "run", *world, "--policy", "csaf11", "--external", "7", "--json",
                             "--domain-id", str(spawner.domain_id), limit_s=120)
        why = ("/formic/early_bird claims agents 0-6, which this run's own drivers (/formic/agent_host_0) drive "
               "(--external: 7)")
        assert outsider.wait(timeout=60) == 0 and why in outsider.output(), outsider.output()[-3000:]
        spawner.formic("host", "agents", "--ids", "7", "--policy", "csaf11", "--once",
                       "--domain-id", str(spawner.domain_id), limit_s=120)
        assert run.wait() == 0, run.output()[-3000:]
        summary = run.json_line()
        two_hosts = Team((("csaf11", tuple(range(7))), ("csaf11", (7,))))  # each host's csaf11 has its own marks
        assert (summary["food"], summary["state_digest"]) == sim_digest(400, two_hosts)
        assert summary["missed_actions"] == 0 and summary["rejected_actions"] == {}
        assert f"claim refused: {why}" in run.output()
    finally:
        spawner.reap_all()


def test_nobody_joined_names_the_refused_claimant(monkeypatch):
    from std_msgs.msg import String

    from formic_ros.errors import NobodyJoined
    from formic_ros.world import ownership
    from formic_ros.world.lockstep import Lockstep

    node = GraphNode()
    world = ownership.Ownership(node, offer_batch=None, subscribe=lambda *args: None, external=(3,),
                                drivers=("/formic/agent_host_0",))
    claim = {"owner": "/formic/early_bird", "token": "t", "agents": [0, 1, 2, 3]}
    world._on_claim(String(data=json.dumps(claim)))
    assert world.owner_of == {} and "t" in world.outsiders
    world._on_claim(String(data=json.dumps({**claim, "token": "u", "agents": [3]})))  # an external agent: fine
    assert world.owner_of == {3: "u"}

    class Executor:
        def spin_once(self, timeout_sec):
            time.sleep(min(timeout_sec, 0.01))

    lockstep = Lockstep(4, log=lambda *a: None, logger=node.get_logger(), deadline_s=0.1, startup_timeout_s=0.05,
                        rate_hz=None, why_absent=world.why_nobody_answered)
    lockstep.inbox.open(0)
    with pytest.raises(NobodyJoined, match=r"refused a claim: /formic/early_bird claims agents 0-2, which this run's "
                                           r"own drivers \(/formic/agent_host_0\) drive \(--external: 3\)"):
        lockstep.await_actions(Executor(), resend=lambda missing: None, started=time.monotonic(), tick=0.0)
    assert np.array_equal(lockstep.inbox.received, np.zeros(4, dtype=bool))
    # a driver whose claim counts and that stays silent is named too, and whether it is still there
    assert "/formic/early_bird claimed agents but did not answer (it has left the graph)" in world.why_nobody_answered()
    node.names = [("early_bird", "/formic")]
    assert world.why_nobody_answered().endswith("/formic/early_bird claimed agents but did not answer")


# --- a step's batch, gated agent by agent against its owners, fills the inbox once ---------
HOST_ACTIONS = "/formic/agent_host_0/actions"


def owned_by_host(agents: list[int]):
    from std_msgs.msg import String

    from formic_ros.world import ownership

    world = ownership.Ownership(GraphNode(), offer_batch=None, subscribe=lambda *args: None)
    world._on_claim(String(data=json.dumps({"owner": "/formic/agent_host_0", "token": "h", "agents": agents,
                                            "actions": HOST_ACTIONS})))
    return world


def test_a_batch_takes_its_owners_agents_and_counts_the_rest():
    from collections import Counter

    world = owned_by_host([0, 2, 5])
    rejected = Counter()
    world.count_into(rejected)
    ids = np.array([5, 0, 1, 2, 7])
    assert world.allowed_batch(HOST_ACTIONS, ids).tolist() == [True, True, False, True, False]
    assert rejected == {"unclaimed": 2}
    assert world.allowed_batch("/formic/stranger/actions", np.array([0, 2])).tolist() == [False, False]
    assert rejected == {"unclaimed": 2, "not owner": 2}


def test_a_gated_batch_fills_the_inbox_once():
    from formic_ros.world.lockstep import ActionInbox, RateLimitedLog

    world = owned_by_host([0, 2, 5])
    inbox = ActionInbox(8, RateLimitedLog(world.node.get_logger(), period_s=60.0), owners=world)
    world.count_into(inbox.rejected)
    inbox.open(3)
    inbox.offer(3, np.array([5, 0, 1, 2, 9]), np.array([4, 1, 2, 3, 0]), "batch", HOST_ACTIONS)
    assert (inbox.heard, inbox.duplicates) == (3, 0)
    inbox.offer(3, np.array([2, 0]), np.array([0, 0]), "batch", HOST_ACTIONS)  # heard already: first answer wins
    assert (inbox.heard, inbox.duplicates) == (3, 2)
    assert dict(inbox.rejected) == {"unknown agent": 1, "unclaimed": 1}
    assert inbox.close().tolist() == [1, -1, 3, -1, -1, 4, -1, -1]
