"""Compiled inner loops of the step rule (numba).

The step is sequential by definition (agents act one at a time in a random order and later
agents see earlier moves, SPEC §1), so it cannot be one NumPy expression; these loops keep
the rule exact and run it at C speed. They only touch arrays owned by :class:`World`;
every rule's meaning is documented in ``world.py``.
"""

from __future__ import annotations

import numba as nb
import numpy as np

from .geometry import DIRECTION_DELTAS

_DR = DIRECTION_DELTAS[:, 0].copy()
_DC = DIRECTION_DELTAS[:, 1].copy()

# Outcome of a JOIN attempt
JOIN_NONE, JOIN_WRONG, JOIN_OK = 0, 1, 2


@nb.njit(cache=True)
def queue_entry_spot(members_count, head, queue_len):
    """First spot behind the last queued agent, or -1 when the queue is full."""
    if members_count == 0:
        return 0
    spot = head + members_count
    return spot if spot < queue_len else -1


@nb.njit(cache=True)
def queue_entry_spots(queue_count, queue_head, queue_len):
    """:func:`queue_entry_spot` of every queue (the observation and the planner read them all).
    Not a numba ufunc: an eagerly typed one compiles at every import (0.5 s), an njit function
    loads from the cache."""
    spots = np.empty(len(queue_count), dtype=np.int64)
    for q in range(len(queue_count)):
        spots[q] = queue_entry_spot(queue_count[q], queue_head[q], queue_len)
    return spots


@nb.njit(cache=True)
def queue_accepts(q, queue_is_cache, queue_resource, resource_remaining, queue_count, load_full):
    """A finite resource whose remaining units do not exceed its queued agents is closed."""
    if queue_is_cache[q]:
        return True
    remaining = resource_remaining[queue_resource[q]]
    return remaining < 0 or remaining > queue_count[q] * load_full


@nb.njit(cache=True)
def find_join(
    agent, row, col, carrying, entry_owner, agent_at, queue_is_cache, queue_resource,
    resource_remaining, queue_count, load_full,
):
    """Queue an agent at (row, col) would join: (outcome, queue). Nearest first, then lowest index."""
    height, width = entry_owner.shape
    best_q = -1
    wrong = False
    for k in range(5):
        if k == 0:
            r, c = row, col
        else:
            r, c = row + _DR[k - 1], col + _DC[k - 1]
            if r < 0 or r >= height or c < 0 or c >= width:
                continue
        q = entry_owner[r, c]
        if q < 0:
            continue
        occupant = agent_at[r, c]
        if occupant != -1 and occupant != agent:
            continue
        if queue_is_cache[q] != carrying:
            wrong = True
            continue
        if not queue_accepts(q, queue_is_cache, queue_resource, resource_remaining, queue_count, load_full):
            continue
        if k == 0:
            return JOIN_OK, q  # distance 0 beats every neighbour
        if best_q == -1 or q < best_q:
            best_q = q
    if best_q >= 0:
        return JOIN_OK, best_q
    if wrong:
        return JOIN_WRONG, -1
    return JOIN_NONE, -1


@nb.njit(cache=True)
def refresh_entries(entry_owner, queue_cells, queue_count, queue_head, queue_len):
    """Recompute which cell is each queue's entry (full queues have none)."""
    entry_owner[:, :] = -1
    for q in range(queue_cells.shape[0]):
        spot = queue_entry_spot(queue_count[q], queue_head[q], queue_len)
        if spot >= 0:
            entry_owner[queue_cells[q, spot, 0], queue_cells[q, spot, 1]] = q


@nb.njit(cache=True)
def act_agents(
    order, actions, grid, agent_at, pos, load, queue_of, spot_of, intensity, last_move,
    queue_cells, queue_is_cache, queue_resource, queue_members, queue_count, queue_head,
    resource_remaining, entry_owner, pheromone, deposit_values, scale_by_intensity, deposits_on, alpha,
    load_full, reward, r_move, r_wait, r_join_right, r_join_wrong, r_join_nothing, r_blocked,
):
    """Phase 2 of a step: every free agent acts once, in ``order``."""
    height, width = grid.shape
    queue_len = queue_cells.shape[1]
    for a in order:
        if queue_of[a] >= 0:
            reward[a] += r_wait
            continue
        act = actions[a]
        if act < 0:
            continue  # no action arrived in time: the agent does nothing (no cost, no deposit)
        row, col = pos[a, 0], pos[a, 1]
        carrying = load[a] > 0
        if act < 4:
            nr, nc = row + _DR[act], col + _DC[act]
            if 0 <= nr < height and 0 <= nc < width and grid[nr, nc] == 0 and agent_at[nr, nc] == -1:
                reward[a] += r_move
                agent_at[row, col] = -1
                agent_at[nr, nc] = a
                pos[a, 0], pos[a, 1] = nr, nc
                last_move[a] = act
            else:
                reward[a] += r_blocked
        else:
            outcome, q = find_join(
                a, row, col, carrying, entry_owner, agent_at, queue_is_cache, queue_resource,
                resource_remaining, queue_count, load_full,
            )
            if outcome == JOIN_OK:
                reward[a] += r_join_right
                spot = queue_entry_spot(queue_count[q], queue_head[q], queue_len)
                er, ec = queue_cells[q, spot, 0], queue_cells[q, spot, 1]
                entry_owner[er, ec] = -1
                agent_at[row, col] = -1
                agent_at[er, ec] = a
                pos[a, 0], pos[a, 1] = er, ec
                queue_members[q, spot] = a
                if queue_count[q] == 0:
                    queue_head[q] = spot
                queue_count[q] += 1
                queue_of[a], spot_of[a] = q, spot
                last_move[a] = -1
                nxt = queue_entry_spot(queue_count[q], queue_head[q], queue_len)
                if nxt >= 0:
                    entry_owner[queue_cells[q, nxt, 0], queue_cells[q, nxt, 1]] = q
            elif outcome == JOIN_WRONG:
                reward[a] += r_join_wrong
            else:
                reward[a] += r_join_nothing
        if carrying:
            # Deposit on the cell the agent stood on at the start of its action (eq. 2: max).
            if deposits_on:
                v = deposit_values[a]
                if scale_by_intensity:
                    v *= intensity[a]
                v = min(v, 1.0)
                if pheromone[row, col] < v:
                    pheromone[row, col] = v
            intensity[a] *= alpha


@nb.njit(cache=True)
def _release(q, spot, queue_members, queue_count, queue_head, queue_of, spot_of, queue_len):
    a = queue_members[q, spot]
    queue_members[q, spot] = -1
    queue_of[a] = -1
    spot_of[a] = -1
    queue_count[q] -= 1
    if queue_count[q] > 0:
        for s in range(queue_len):
            if queue_members[q, s] >= 0:
                queue_head[q] = s
                break
    else:
        queue_head[q] = 0


@nb.njit(cache=True)
def serve_queues(
    agent_at, pos, load, queue_of, spot_of, intensity, queue_cells, queue_is_cache,
    queue_resource, queue_members, queue_count, queue_head, resource_remaining,
    gather_ticks, dropoff_ticks, load_full, reward, r_collect, r_deposit, depleted,
    gather_holds, dropoff_holds, serve_after_move_up,
):
    """Phase 3: queues advance, spot 0 is served; returns food ticks unloaded at the nest.
    ``r_collect`` holds each resource's collection reward.

    Timing (``WorldConfig.timing``): with ``serve_after_move_up`` False a queue that moves up
    serves nobody in that step; with ``gather_holds``/``dropoff_holds`` a service that has
    completed is only released at the agent's next service step (one step longer).
    """
    queue_len = queue_cells.shape[1]
    unloaded = 0
    for q in range(queue_cells.shape[0]):
        if queue_count[q] == 0:
            continue
        moved_up = False
        if queue_head[q] > 0 and agent_at[queue_cells[q, 0, 0], queue_cells[q, 0, 1]] == -1:
            # Spot 0 is free: every queued agent moves up one spot (members are contiguous).
            head = queue_head[q]
            for s in range(head, head + queue_count[q]):
                a = queue_members[q, s]
                agent_at[queue_cells[q, s, 0], queue_cells[q, s, 1]] = -1
                agent_at[queue_cells[q, s - 1, 0], queue_cells[q, s - 1, 1]] = a
                pos[a, 0], pos[a, 1] = queue_cells[q, s - 1, 0], queue_cells[q, s - 1, 1]
                queue_members[q, s - 1] = a
                queue_members[q, s] = -1
                spot_of[a] = s - 1
            queue_head[q] = head - 1
            moved_up = True
        if queue_head[q] != 0 or (moved_up and not serve_after_move_up):
            continue
        a = queue_members[q, 0]
        amount = 0
        if queue_is_cache[q]:
            if load[a] > 0:
                amount = min(dropoff_ticks, load[a])
                load[a] -= amount
                unloaded += amount
            if load[a] == 0 and not (dropoff_holds and amount > 0):
                reward[a] += r_deposit
                _release(q, 0, queue_members, queue_count, queue_head, queue_of, spot_of, queue_len)
        else:
            res = queue_resource[q]
            if load[a] < load_full:
                amount = min(gather_ticks, load_full - load[a])
                if resource_remaining[res] >= 0:
                    amount = min(amount, resource_remaining[res])
                    resource_remaining[res] -= amount
                load[a] += amount
            if load[a] == load_full and not (gather_holds and amount > 0):
                reward[a] += r_collect[res]
                intensity[a] = 1.0
                _release(q, 0, queue_members, queue_count, queue_head, queue_of, spot_of, queue_len)
            if resource_remaining[res] == 0:
                # Depleted: everyone still queued is released where they stand; a full agent
                # held for its last service step leaves now, with its load.
                if queue_members[q, 0] >= 0 and load[queue_members[q, 0]] == load_full:
                    full = queue_members[q, 0]
                    reward[full] += r_collect[res]
                    intensity[full] = 1.0
                for s in range(queue_len):
                    if queue_members[q, s] >= 0:
                        _release(q, s, queue_members, queue_count, queue_head, queue_of, spot_of, queue_len)
                depleted[q] = True
    return unloaded


@nb.njit(cache=True)
def valid_actions(
    grid, agent_at, pos, load, queue_of, entry_owner, queue_is_cache, queue_resource,
    resource_remaining, queue_count, load_full, mask,
):
    """Environment validity (SPEC §4): moves into free cells; JOIN when a right-type queue is
    joinable. Queued agents have no valid action (whatever they send is ignored)."""
    height, width = grid.shape
    for a in range(pos.shape[0]):
        for k in range(5):
            mask[a, k] = False
        if queue_of[a] >= 0:
            continue
        row, col = pos[a, 0], pos[a, 1]
        for d in range(4):
            nr, nc = row + _DR[d], col + _DC[d]
            if 0 <= nr < height and 0 <= nc < width and grid[nr, nc] == 0 and agent_at[nr, nc] == -1:
                mask[a, d] = True
        outcome, _ = find_join(
            a, row, col, load[a] > 0, entry_owner, agent_at, queue_is_cache, queue_resource,
            resource_remaining, queue_count, load_full,
        )
        mask[a, 4] = outcome == JOIN_OK
