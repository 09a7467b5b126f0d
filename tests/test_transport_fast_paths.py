"""An agent host polls without sleeping only right after a batched answer for the whole team
(the batch gating and the inbox's fast path: tests/test_ownership.py)."""

from __future__ import annotations

import pytest

pytest.importorskip("rclpy")
pytest.importorskip("formic_interfaces.msg")


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
