"""A process that keeps freed memory (formic_runtime.memory) reuses the buffers a policy's
forward pass frees instead of faulting fresh pages in for them at every step."""

from __future__ import annotations

import json
import subprocess
import sys

import pytest

PROBE = """
import json, resource, sys
from formic_runtime.memory import keep_freed_memory
applied = keep_freed_memory() if sys.argv[1] == "keep" else None
from formic_runtime.threads import configure_threads
configure_threads(1)
from formic_agent.policy import AgentBatch
from formic_runtime.team import Team
from formic_world import World, WorldConfig, generate_scenario
scenario = generate_scenario(WorldConfig(height=64, width=64, n_agents=128), 1)
team = Team.parse("formic", 128)
team.build()
team.reset(128, 1)
world = World(scenario)
result = world.last_result
faults = []
for t in range(25):  # 5 to warm up, then 20 counted
    faults.append(resource.getrusage(resource.RUSAGE_SELF).ru_minflt)
    batch = AgentBatch.from_world(world, observations=result.observations, action_mask=result.action_mask)
    result = world.step(team.act(batch, world))
print(json.dumps({"applied": applied, "faults": resource.getrusage(resource.RUSAGE_SELF).ru_minflt - faults[5]}))
"""


def probe(mode: str) -> dict:
    done = subprocess.run([sys.executable, "-c", PROBE, mode], capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr
    return json.loads(done.stdout)


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="glibc's malloc")
def test_a_policy_reuses_its_freed_buffers_instead_of_faulting_them_in_every_step():
    default, kept = probe("default"), probe("keep")
    assert kept["applied"] is True
    # 128 learned agents: glibc's defaults fault ~550 pages (2.2 MB, zeroed) back in every step
    assert default["faults"] > 20 * 100
    assert kept["faults"] < default["faults"] / 10
