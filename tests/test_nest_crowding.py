"""analysis/nest_crowding.py: crowding at the nest, counted on a hand-built world."""

from __future__ import annotations

import numpy as np
from conftest import agent, build_world

from formic_world.geometry import JOIN, NORTH, SOUTH
from formic_world.scenario import ResourceSpec
from analysis.nest_crowding import CrowdCounter


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


def test_joins_are_counted_against_the_agents_that_could_join():
    # 16x16: NE cache queue spot 0 is (6, 8), NW's is (7, 6); a resource at (1, 12) has its queue entry at (2, 12).
    world = build_world([agent(6, 9, loaded=True), agent(6, 6, loaded=True), agent(2, 11), agent(2, 13)],
                        resources=[ResourceSpec(1, 12, SOUTH, 0)])
    counter = CrowdCounter(radius=4)
    counter(world)  # all four may JOIN: 0 and 1 a cache queue, 2 and 3 the resource's queue
    world.step(np.array([JOIN, NORTH, JOIN, JOIN]))  # 1 walks away; 2 and 3 race for one entry cell
    counter(world)
    table = counter.table()
    assert table["cache_join"] == 0.5  # agent 0 queued, agent 1 did not
    assert table["resource_join"] == 0.5  # whichever acted first queued; the entry then moved out of reach
