"""Lockstep across a lossy link: the world in one network namespace, 16 per-agent learned
agents in another, joined by a userspace forwarder adding 20 ms delay each way and dropping 2%
of packets (seeded). With the shipped Fast DDS profile (50 ms heartbeat) a lost sample is
repaired long before the 1 s deadline (Fast DDS's default 3 s heartbeat gave ~1.1 steps/s and
~67% missed actions here). Needs root and ``ip netns``; skipped elsewhere."""

import json
import subprocess
import sys

import pytest

from benchmarks.netsim import lockstep_across_link, namespaces_available

pytestmark = pytest.mark.skipif(not namespaces_available(), reason="cannot create network namespaces")


def test_lockstep_survives_lossy_link(tmp_path):
    pytest.importorskip("rclpy")
    summary = lockstep_across_link(agents=16, steps=60, size=32, seed=0, delay_ms=20, loss=0.02,
                                   prefix="fxlt", limit_s=150, workdir=str(tmp_path))
    n_actions = 16 * 60
    # The speed (5.9 steps/s measured, 1.1 with Fast DDS's defaults) is a benchmark figure
    # (`sudo .venv/bin/python benchmarks/netsim.py bench`, docs/ros.md), not asserted here; a lost sample
    # repaired only at the default 3 s heartbeat shows as missed actions, which are.
    assert summary["missed_actions"] <= 0.01 * n_actions, summary
    if summary["missed_actions"] == 0:
        sim = subprocess.run([sys.executable, "-m", "formic_cli.main", "sim", "--agents", "16", "--size", "32",
                              "--steps", "60", "--seed", "0", "--json", "--out", str(tmp_path / "sim")],
                             capture_output=True, text=True, timeout=120, check=True)
        assert json.loads(sim.stdout.strip().splitlines()[-1])["state_digest"] == summary["state_digest"]
