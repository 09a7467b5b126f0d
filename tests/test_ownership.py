"""Only an agent's owner drives it: a spoofing node changes nothing, and two nodes claiming one
agent give a clear error with the first owner kept. Real processes, bounded and reaped."""

from __future__ import annotations

import time

import pytest

pytest.importorskip("rclpy")
pytest.importorskip("formic_interfaces.msg")

from ros_helpers import ROOT, Spawner, fresh_domain_id  # noqa: E402

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
        run = spawner.formic("run", "run", "--agents", "8", "--size", "24", "--seed", "0", "--steps", "40",
                             "--policy", "random", "--external", "2", "--deadline-ms", "5000", "--json",
                             "--domain-id", str(spawner.domain_id), limit_s=120)
        assert run.wait() == 0, run.output()[-3000:]
        time.sleep(1)  # the refused one idles (it may miss the end): reaped below
        summary = run.json_line()
        assert summary["missed_actions"] == 0 and summary["last_answered_step"] == [39] * 8
        assert "claim refused, first owner kept" in run.output()
        refused = ["is driven by another node" in p.output() for p in (first, second)]
        assert sorted(refused) == [False, True], "exactly one of them was refused"
    finally:
        spawner.reap_all()
