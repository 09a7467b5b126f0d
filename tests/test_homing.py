"""analysis/homing.py: trips, deliveries and loads never delivered, counted on a hand-built world."""

from __future__ import annotations

import numpy as np
from conftest import agent, build_world

from formic_world.geometry import EAST, JOIN, SOUTH, WEST
from formic_world.scenario import ResourceSpec
from analysis.homing import TripCounter


def test_a_pickup_walk_and_deposit_is_one_loaded_trip_and_a_lost_load_counts_from_step_0():
    # 16x16: the resource at (1, 12) faces south, its queue's spot 0 is (2, 12); the north-east
    # cache queue's spot 0 is (6, 8). Agent 0 starts loaded on that spot, unloads by step 2 and
    # steps aside; agent 1 queues at the resource (gathering at steps 2-11, queued until 12),
    # walks to (6, 9), queues at the cache and has unloaded at step 21; agent 2 starts loaded
    # far from the nest and never delivers.
    world = build_world([agent(6, 8, loaded=True, cache_queue=1), agent(2, 11), agent(13, 1, loaded=True)],
                        resources=[ResourceSpec(1, 12, SOUTH, 0)])
    agent1 = [EAST] + [JOIN] * 11 + [SOUTH] * 3 + [WEST] * 3 + [SOUTH, JOIN, JOIN, JOIN]
    agent0 = [JOIN, JOIN, EAST, SOUTH] + [JOIN] * (len(agent1) - 4)
    counter = TripCounter()
    for actions in zip(agent0, agent1, [JOIN] * len(agent1)):
        world.step(np.array(actions))
        counter(world)
    assert world.t == 22 and world.score == 2.0
    assert counter.loaded_trips == [21 - 2]  # agent 1's; agent 0's load began before step 0
    assert counter.empty_trips == []  # nobody picked up after a delivery
    table = counter.table()
    assert table["deliveries_per_agent"] == 2 / 3
    assert table["carrying"] == (1 + 19 + 22) / (3 * 22)  # after steps 1, 2-20 and all 22
    assert table["undelivered"] == 22 / (3 * 22)  # agent 2, from step 0 to the end
