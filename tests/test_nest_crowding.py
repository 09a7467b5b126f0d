"""scripts/nest_crowding.py: crowding at the nest, counted on a hand-built world."""

from __future__ import annotations

import numpy as np
from conftest import agent, build_world

from formic_world.geometry import JOIN, NORTH
from scripts.nest_crowding import CrowdCounter


def test_crowd_queue_and_held_docks_are_counted_exactly():
    # 16x16: the nest centre is (7.5, 7.5); NW cache queue spot 0 is (7, 6), NE's is (6, 8).
    world = build_world([agent(5, 5, loaded=True), agent(0, 0, loaded=True), agent(7, 6, loaded=True, cache_queue=0),
                         agent(6, 8), agent(5, 10, loaded=True)])
    counter = CrowdCounter(radius=4)
    counter(world)  # step 0: agents 0 and 4 crowd (agent 1 is 7.5 cells away), 2 is queued, 3 holds a dock
    world.step(np.array([NORTH, JOIN, JOIN, JOIN, JOIN]))  # 0 moves to (4, 5): 3.5 cells away, still in the crowd
    counter(world)
    table = counter.table()
    assert table["crowd"] == 2.0 and table["in_cache_queues"] == 1.0 and table["docks_held"] == 1.0
    assert table["crowd_moving"] == 0.5  # of the 2 crowd agents of step 0, one moved
