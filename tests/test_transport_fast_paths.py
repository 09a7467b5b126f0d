"""The per-step shortcuts of the transports keep their rules: a batch is gated agent by agent
against its owner (owned agents taken, the others counted as before), a batch already heard is a
duplicate, and an agent host polls without sleeping only right after a batched answer for the
whole team."""

from __future__ import annotations

import json
from collections import Counter

import numpy as np
import pytest

pytest.importorskip("rclpy")
pytest.importorskip("formic_interfaces.msg")

from std_msgs.msg import String  # noqa: E402

from formic_ros.world.lockstep import ActionInbox, RateLimitedLog  # noqa: E402
from formic_ros.world.ownership import Ownership  # noqa: E402

HOST_ACTIONS = "/formic/agent_host_0/actions"


class QuietNode:
    """The little of an rclpy node Ownership uses before any graph lookup."""

    def get_namespace(self):
        return "/formic"

    def get_logger(self):
        class Logger:
            def info(self, text):
                pass

            error = warning = info
        return Logger()

    def create_publisher(self, *args):
        class Publisher:
            def publish(self, msg):
                pass
        return Publisher()

    def create_timer(self, *args):
        return None


def owned_by_host(agents: list[int]) -> Ownership:
    world = Ownership(QuietNode(), offer_batch=None, subscribe=lambda *args: None)
    world._on_claim(String(data=json.dumps({"owner": "/formic/agent_host_0", "token": "h", "agents": agents,
                                            "actions": HOST_ACTIONS})))
    return world


def test_a_batch_takes_its_owners_agents_and_counts_the_rest():
    world = owned_by_host([0, 2, 5])
    rejected = Counter()
    world.count_into(rejected)
    ids = np.array([5, 0, 1, 2, 7])
    assert world.allowed_batch(HOST_ACTIONS, ids).tolist() == [True, True, False, True, False]
    assert rejected == {"unclaimed": 2}
    assert world.allowed_batch("/formic/stranger/actions", np.array([0, 2])).tolist() == [False, False]
    assert rejected == {"unclaimed": 2, "not owner": 2}


def test_a_gated_batch_fills_the_inbox_once():
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


@pytest.mark.parametrize("transport, agents, since_s, wait_s", [
    ("batched", 4, 0.001, 0.0),  # just answered for the whole team: polls
    ("batched", 4, 0.010, 0.2),  # the world is slow this step: sleeps
    ("batched", 3, 0.001, 0.2),  # one of several hosts
    ("per-agent", 4, 0.001, 0.2),
])
def test_a_host_polls_only_right_after_answering_a_whole_batched_team(monkeypatch, transport, agents, since_s,
                                                                      wait_s):
    from formic_ros.drivers import agent_host
    from formic_world import WorldConfig, generate_scenario

    host = agent_host.AgentHost.__new__(agent_host.AgentHost)  # its state only: no node
    host.transport, host.expected, host.answered_at = transport, agents, 100.0
    host.scenario = None
    monkeypatch.setattr(agent_host.time, "monotonic", lambda: 100.0 + since_s)
    assert host.wait_s() == agent_host.BLOCK_S  # no scenario yet
    host.scenario = generate_scenario(WorldConfig(height=16, width=16, n_agents=4), seed=1)
    assert host.wait_s() == wait_s
