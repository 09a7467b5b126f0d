"""Centralized planner baseline (SPEC §7): full observability, greedy allocation, local paths.

The upper bound of the paper's comparisons. Every step it allocates free agents to queues
greedily (distance to the nest plus the expected queueing delay), moves them along
breadth-first distance fields with local detours around other agents, admits loaded agents to
the nest a few at a time (else the team gridlocks there), and JOINs next to the target entry.
The rules and the reasons behind them are in docs/baselines.md.
"""

from __future__ import annotations

import numba as nb
import numpy as np

from formic_agent.policy import CentralPolicy
from formic_world.geometry import DIRECTION_DELTAS, FREE, JOIN
from formic_world.kernels import JOIN_OK, find_join, queue_entry_spots

UNREACHABLE = np.int32(1 << 28)
NO_TARGET = -1
SPREAD = -2  # the agent heads for a random cell: no resource can take it
SIDESTEP_SLACK = 2  # a detour around a waiting agent may cost this many extra steps

_DR = DIRECTION_DELTAS[:, 0].copy()
_DC = DIRECTION_DELTAS[:, 1].copy()


# ----------------------------------------------------------------------------- kernels
@nb.njit(cache=True)
def bfs_field(passable, sources):
    """4-connected breadth-first distance from any of ``sources`` (k, 2) over passable cells."""
    height, width = passable.shape
    dist = np.full((height, width), UNREACHABLE, dtype=np.int32)
    queue = np.empty(height * width, dtype=np.int64)
    head, tail = 0, 0
    for k in range(sources.shape[0]):
        r, c = sources[k, 0], sources[k, 1]
        if dist[r, c] != 0:
            dist[r, c] = 0
            queue[tail] = r * width + c
            tail += 1
    while head < tail:
        cell = queue[head]
        head += 1
        r, c = cell // width, cell % width
        nd = dist[r, c] + 1
        for d in range(4):
            nr, nc = r + _DR[d], c + _DC[d]
            if 0 <= nr < height and 0 <= nc < width and passable[nr, nc] and dist[nr, nc] > nd:
                dist[nr, nc] = nd
                queue[tail] = nr * width + nc
                tail += 1
    return dist


@nb.njit(cache=True)
def _local_astar(field, passable, agent_at, row, col, radius):
    """First move of the best path that treats every agent as an obstacle within ``radius``.

    Breadth-first search over agent-free cells of the window around the agent; a cell reached
    in k steps scores k + field (the exact remaining distance ignoring agents). Returns
    (direction, score), or (-1, UNREACHABLE) when no agent-free cell can be reached.
    """
    height, width = passable.shape
    size = 2 * radius + 1
    depth = np.full((size, size), -1, dtype=np.int64)
    first = np.full((size, size), -1, dtype=np.int64)
    queue = np.empty(size * size, dtype=np.int64)
    depth[radius, radius] = 0
    queue[0] = radius * size + radius
    head, tail = 0, 1
    best_dir, best_score, best_field = -1, UNREACHABLE, UNREACHABLE
    while head < tail:
        cell = queue[head]
        head += 1
        lr, lc = cell // size, cell % size
        for d in range(4):
            mr, mc = lr + _DR[d], lc + _DC[d]
            if mr < 0 or mr >= size or mc < 0 or mc >= size or depth[mr, mc] >= 0:
                continue
            r, c = row + mr - radius, col + mc - radius
            if r < 0 or r >= height or c < 0 or c >= width or not passable[r, c] or agent_at[r, c] >= 0:
                continue
            depth[mr, mc] = depth[lr, lc] + 1
            first[mr, mc] = d if (lr == radius and lc == radius) else first[lr, lc]
            queue[tail] = mr * size + mc
            tail += 1
            remaining = field[r, c]
            if remaining >= UNREACHABLE:
                continue
            score = depth[mr, mc] + remaining
            if score < best_score or (score == best_score and remaining < best_field):
                best_dir, best_score, best_field = first[mr, mc], score, remaining
    return best_dir, best_score


@nb.njit(cache=True)
def plan_moves(
    movers, pos, field_of, fields, passable, agent_at, priority, queued, waiting, stuck, last_dir,
    horizon, slack, stuck_limit, tie_offset, actions,
):
    """Moves of every agent in ``movers`` toward its field's source (SPEC §7 path rules).

    ``waiting[a]``: the agent stands where it wants to be (it sends JOIN or a no-op and will
    not leave on its own). ``actions`` holds the agents' fallback actions (their no-op) on entry
    and their moves on exit. A static blocker of lower ``priority`` (distinct per agent) steps
    aside for the agent it blocks.
    """
    height, width = passable.shape
    n = pos.shape[0]
    desired = np.full(n, -1, dtype=np.int64)  # direction one step closer, preferring a free cell
    claimed = np.zeros((height, width), dtype=np.bool_)  # free cells another mover already chose
    for i in range(movers.shape[0]):
        a = movers[i]
        f = fields[field_of[a]]
        r, c = pos[a, 0], pos[a, 1]
        here = f[r, c]
        if here == 0 or here >= UNREACHABLE:
            continue
        best_rank = 9
        for k in range(4):
            d = (k + tie_offset + a) % 4  # vary ties between agents so streams spread out
            nr, nc = r + _DR[d], c + _DC[d]
            if not (0 <= nr < height and 0 <= nc < width) or not passable[nr, nc]:
                continue
            if f[nr, nc] < here:  # one step closer
                # Rank: free and unclaimed cells first; undoing the last move (a sidestep) last.
                taken = agent_at[nr, nc] >= 0 or claimed[nr, nc]
                rank = (2 if taken else 0) + (1 if last_dir[a] >= 0 and d == (last_dir[a] + 2) % 4 else 0)
                if rank < best_rank:
                    best_rank, desired[a] = rank, d
        if desired[a] >= 0:
            claimed[r + _DR[desired[a]], c + _DC[desired[a]]] = True
    yielding = np.zeros(n, dtype=np.bool_)
    for i in range(movers.shape[0]):
        a = movers[i]
        d = desired[a]
        if d < 0:
            continue
        f = fields[field_of[a]]
        r, c = pos[a, 0], pos[a, 1]
        nr, nc = r + _DR[d], c + _DC[d]
        b = agent_at[nr, nc]
        if b < 0:
            actions[a] = d
            continue
        # Blocked. A moving blocker usually clears the cell: wait behind it.
        b_static = queued[b] or waiting[b] or desired[b] < 0 or stuck[b] >= stuck_limit
        mutual = (not queued[b]) and desired[b] >= 0 and (
            pos[b, 0] + _DR[desired[b]] == r and pos[b, 1] + _DC[desired[b]] == c
        )
        if not (b_static or mutual or stuck[a] >= stuck_limit):
            actions[a] = d
            continue
        if mutual and priority[a] > priority[b]:
            actions[a] = d  # head-on: the other one steps aside
            continue
        step, score = _local_astar(f, passable, agent_at, r, c, horizon)
        if step >= 0 and score <= f[r, c] + slack:
            actions[a] = step  # a cheap sidestep around the blocker
        elif priority[a] > priority[b] and not queued[b]:
            yielding[b] = True  # b makes room; a keeps pushing and moves once b has gone
            actions[a] = d
        elif step >= 0:
            actions[a] = step
        else:
            # Boxed in behind an agent that cannot give way: ask another neighbour instead.
            actions[a] = d
            best_total = UNREACHABLE
            for e in range(4):
                mr, mc = r + _DR[e], c + _DC[e]
                if not (0 <= mr < height and 0 <= mc < width) or not passable[mr, mc]:
                    continue
                o = agent_at[mr, mc]
                if o < 0 or queued[o] or priority[o] > priority[a]:
                    continue
                if f[mr, mc] < best_total:
                    best_total, actions[a] = f[mr, mc], e
            o = agent_at[r + _DR[actions[a]], c + _DC[actions[a]]]
            if not queued[o] and priority[o] < priority[a]:
                yielding[o] = True
    for a in range(n):
        if not yielding[a]:
            continue
        # Step aside: a free neighbour, the one that costs the agent least on its own field.
        r, c = pos[a, 0], pos[a, 1]
        f = fields[field_of[a]]
        best, best_value = -1, UNREACHABLE + 1
        for d in range(4):
            nr, nc = r + _DR[d], c + _DC[d]
            if 0 <= nr < height and 0 <= nc < width and passable[nr, nc] and agent_at[nr, nc] < 0:
                if f[nr, nc] < best_value:
                    best, best_value = d, f[nr, nc]
        if best >= 0:
            actions[a] = best
    return actions


# ------------------------------------------------------------------------------ policy
class CentralizedPlanner(CentralPolicy):
    """Greedy centralized allocation plus per-agent shortest paths around other agents."""

    name = "planner"

    def __init__(
        self,
        distance_weight: float = 1.0,
        horizon: int = 6,
        stuck_limit: int = 4,
        hold_radius: int = 6,
        nest_capacity: int | None = 8,
    ) -> None:
        """``distance_weight`` scales a target's distance to the nest in its cost; ``horizon``
        is the radius of the A* window with agents as obstacles; an agent that has not moved
        for ``stuck_limit`` steps treats every blocker as static (and searches around it);
        at most ``nest_capacity`` loaded agents walk within ``hold_radius`` of the caches
        (None: no limit)."""
        self.distance_weight = distance_weight
        self.horizon = horizon
        self.stuck_limit = stuck_limit
        self.hold_radius = hold_radius
        self.nest_capacity = nest_capacity
        self.reset(0, 0)

    def reset(self, n_agents: int, seed: int) -> None:
        self.rng = np.random.default_rng([seed, 23])
        self.target = np.full(n_agents, NO_TARGET, dtype=np.int64)  # queue index, or SPREAD
        self.spread_cell = np.zeros((n_agents, 2), dtype=np.int64)
        self.target_anchor = np.zeros((n_agents, 2), dtype=np.int64)  # resource cell when assigned
        self.last_pos = np.full((n_agents, 2), -1, dtype=np.int64)
        self.stuck = np.zeros(n_agents, dtype=np.int64)
        self._fields: dict[tuple[int, int], int] = {}
        self._field_array = np.zeros((0, 1, 1), dtype=np.int32)
        self._grid_key = b""

    # ------------------------------------------------------------------ fields
    def _sync_grid(self, world) -> None:
        """Distance fields depend on the static grid only: drop them when it changes."""
        key = world.grid.tobytes()
        if key != self._grid_key:
            self._grid_key = key
            self._passable = world.grid == FREE
            self._fields = {}
            self._field_array = np.zeros((64, *world.grid.shape), dtype=np.int32)
            self._nest_field = bfs_field(self._passable, world.queue_cells[:4, 0])  # to the caches' spot 0

    def _field(self, cell: tuple[int, int]) -> int:
        """Index of the distance field towards ``cell`` (computed on first use)."""
        cell = (int(cell[0]), int(cell[1]))
        index = self._fields.get(cell)
        if index is None:
            index = len(self._fields)
            if index == len(self._field_array):  # grow by doubling: fields are reused for long
                self._field_array = np.concatenate([self._field_array, np.zeros_like(self._field_array)])
            self._field_array[index] = bfs_field(self._passable, np.array([cell], dtype=np.int64))
            self._fields[cell] = index
        return index

    @staticmethod
    def _queue_targets(world) -> np.ndarray:
        """Cell each queue's agents head for: its entry; one cell further out when the entry is
        still held by the agent just served (waiting beside it would box that agent in), and
        past the queue's end when the queue is full."""
        spot = queue_entry_spots(world.queue_count, world.queue_head, world.config.queue_len)
        full = spot < 0
        cells = world.queue_cells[np.arange(len(spot)), spot].copy()  # full (-1): replaced below
        outward = world.queue_cells[:, 1] - world.queue_cells[:, 0]
        held = ~full & (world.agent_at[cells[:, 0], cells[:, 1]] >= 0)
        cells[full] = world.queue_cells[full, -1] + outward[full]
        cells[held] += outward[held]
        return cells

    # --------------------------------------------------------------- allocation
    def _service_steps(self, world) -> np.ndarray:
        """Steps a queue spends per agent (the next one moves up as the served one leaves;
        under the reference timing that move-up step serves nobody)."""
        cfg = world.config
        move_up = 0 if cfg.serve_after_move_up else 1
        return np.where(world.queue_is_cache, cfg.dropoff_steps, cfg.gather_steps) + move_up

    def _backlog(self, world, service: np.ndarray) -> np.ndarray:
        """Steps until each queue has served the agents already in it."""
        backlog = world.queue_count * service
        q = np.flatnonzero(world.queue_members[:, 0] >= 0)  # queues serving an agent now
        a = world.queue_members[q, 0]
        done = np.where(world.queue_is_cache[q], world.load_full - world.load[a], world.load[a])
        rate = np.where(world.queue_is_cache[q], world.dropoff_ticks, world.gather_ticks)
        backlog[q] -= done // rate
        return backlog

    def _finish_time(self, backlog: int, arrivals: list[int], service: int) -> int:
        """When a queue finishes its backlog plus agents arriving after ``arrivals`` steps."""
        t = backlog
        for d in sorted(arrivals):
            t = max(t, d) + service
        return t

    def _assign(self, world, agents: np.ndarray, queues: np.ndarray, targets: np.ndarray,
                capacity: np.ndarray) -> None:
        """Greedy: the cheapest queue goes to its closest free agent, repeat (SPEC §7)."""
        if len(agents) == 0 or len(queues) == 0:
            return
        service = self._service_steps(world)
        backlog = self._backlog(world, service)
        fields = np.array([self._field(targets[q]) for q in queues])
        rows, cols = world.pos[agents, 0], world.pos[agents, 1]
        dist = self._field_array[fields[:, None], rows[None, :], cols[None, :]].astype(np.int64)  # (Q, U)
        slot_of = np.full(len(world.queue_cells), -1)
        slot_of[queues] = np.arange(len(queues))
        bound = np.flatnonzero((self.target >= 0) & (slot_of[np.maximum(self.target, 0)] >= 0))
        slots = slot_of[self.target[bound]]
        bound_dist = self._field_array[fields[slots], world.pos[bound, 0], world.pos[bound, 1]]
        inbound: list[list[int]] = [[] for _ in queues]
        for i, d in zip(slots, bound_dist):
            inbound[i].append(int(d))
        finish = np.array([self._finish_time(backlog[q], inbound[i], service[q])
                           for i, q in enumerate(queues)])
        if world.queue_is_cache[queues[0]]:
            base = np.zeros(len(queues))
        else:
            anchors = world.queue_cells[queues, 0]
            base = self.distance_weight * self._nest_field[anchors[:, 0], anchors[:, 1]].astype(float)
        free = np.ones(len(agents), dtype=bool)
        capacity = capacity.copy()
        for _ in range(len(agents)):
            masked = np.where(free[None, :], dist, UNREACHABLE)
            closest = masked.argmin(axis=1)
            closest_dist = masked[np.arange(len(queues)), closest]
            ok = (capacity > 0) & (closest_dist < UNREACHABLE)
            if not ok.any():
                return
            cost = base + np.maximum(finish - closest_dist, 0)
            i = np.lexsort((closest_dist, np.where(ok, cost, np.inf)))[0]
            j = closest[i]
            q = queues[i]
            agent = agents[j]
            self.target[agent] = q
            self.target_anchor[agent] = world.queue_cells[q, 0]
            free[j] = False
            capacity[i] -= 1
            inbound[i].append(int(closest_dist[i]))
            finish[i] = self._finish_time(backlog[q], inbound[i], service[q])

    def _resource_capacity(self, world, queues: np.ndarray) -> np.ndarray:
        """How many more agents each resource queue may receive (finite: its units left)."""
        remaining = world.resource_remaining[world.queue_resource[queues]]
        infinite = remaining < 0
        members = world.queue_members[queues]  # (Q, queue_len), -1: a free spot
        promised = np.where(members >= 0, world.load_full - world.load[members], 0).sum(axis=1)
        left = remaining - promised
        units = -(-np.maximum(left, 0) // world.load_full)  # a partial unit still feeds one agent
        assigned = (self.target[None, :] == queues[:, None]).sum(axis=1)
        return np.where(infinite, len(self.target) + 1, units - assigned)

    def _update_assignments(self, world, targets: np.ndarray) -> None:
        """Drop targets that are reached or void, then assign every free agent without one."""
        free = ~world.queued
        carrying = world.carrying
        target = self.target
        target[~free] = NO_TARGET  # joined a queue: the target is reached
        has_queue = target >= 0
        is_cache = has_queue & world.queue_is_cache[np.maximum(target, 0)]
        target[(has_queue & (is_cache != carrying)) | ((target == SPREAD) & carrying)] = NO_TARGET
        target[has_queue & is_cache] = NO_TARGET  # caches are re-chosen every step
        at_resource = np.flatnonzero((target >= 0) & ~is_cache)
        respawned = (world.queue_cells[target[at_resource], 0] != self.target_anchor[at_resource]).any(axis=1)
        target[at_resource[respawned]] = NO_TARGET  # a finite resource moved: its target is void
        resources = np.flatnonzero(~world.queue_is_cache)
        if len(resources):
            capacity = self._resource_capacity(world, resources)
            for i in np.flatnonzero(capacity < 0):
                # Agents outside the plan took units: release the inbound agents farthest away.
                q = resources[i]
                mine = np.flatnonzero(target == q)
                field = self._field_array[self._field(targets[q])]
                farthest = mine[np.argsort(-field[world.pos[mine, 0], world.pos[mine, 1]], kind="stable")]
                target[farthest[: -capacity[i]]] = NO_TARGET
            capacity = np.maximum(self._resource_capacity(world, resources), 0)
            seekers = np.flatnonzero(free & ~carrying & ((target == NO_TARGET) | (target == SPREAD)))
            self._assign(world, seekers, resources, targets, capacity)
        loaded = np.flatnonzero(free & carrying & (target == NO_TARGET))
        self._assign(world, loaded, np.arange(4), targets, np.full(4, len(target) + 1))
        self._spread(world, np.flatnonzero(free & ~carrying & (target == NO_TARGET)))

    def _spread(self, world, agents: np.ndarray) -> None:
        """Agents no resource can take go to distinct random free cells (SPEC §7)."""
        if len(agents) == 0:
            return
        open_cells = self._passable & (self._nest_field < UNREACHABLE)
        taken = self.spread_cell[self.target == SPREAD]
        open_cells[taken[:, 0], taken[:, 1]] = False
        cells = np.flatnonzero(open_cells)
        chosen = self.rng.choice(cells, size=min(len(agents), len(cells)), replace=False)
        agents = agents[: len(chosen)]
        self.spread_cell[agents] = np.stack(np.unravel_index(chosen, open_cells.shape), axis=1)
        self.target[agents] = SPREAD

    # ------------------------------------------------------------------ acting
    def _hold_at_gate(self, world, candidates: np.ndarray) -> np.ndarray:
        """Admission to the nest: loaded agents wait at ``hold_radius`` from the caches while
        ``nest_capacity`` loaded agents are already walking inside (queued ones not counted),
        so that agents leaving the caches are never walled in. Closest to the nest go first."""
        if self.nest_capacity is None:
            return np.zeros(len(candidates), dtype=bool)
        loaded = candidates & world.carrying
        distance = self._nest_field[world.pos[:, 0], world.pos[:, 1]]
        inside = loaded & (distance <= self.hold_radius)
        gate = np.flatnonzero(loaded & (distance > self.hold_radius) & (distance <= self.hold_radius + 1))
        room = max(self.nest_capacity - int(inside.sum()), 0)
        holding = np.zeros(len(candidates), dtype=bool)
        holding[gate[np.argsort(-self.stuck[gate], kind="stable")][room:]] = True  # longest wait enters
        return holding

    def _priority(self, world, holding: np.ndarray) -> np.ndarray:
        """Who makes room for whom: an agent standing in a queue's cells without being queued
        (it just finished service and blocks the queue) first, then agents stuck for a while,
        then loaded agents, and agents held at the nest's gate last; lower id breaks ties."""
        n = world.config.n_agents
        on_queue = np.zeros(world.grid.shape, dtype=bool)
        on_queue[world.queue_cells[..., 0], world.queue_cells[..., 1]] = True
        blocking = on_queue[world.pos[:, 0], world.pos[:, 1]] & ~world.queued
        level = 8 * blocking + 4 * (self.stuck >= self.stuck_limit) + 2 * world.carrying + ~holding
        return level.astype(np.int64) * n + (n - 1 - np.arange(n))

    def act_world(self, world) -> np.ndarray:
        n = world.config.n_agents
        if len(self.target) != n:
            self.reset(n, world.scenario.seed)
        self._sync_grid(world)
        step = world.pos - self.last_pos
        moved = (np.abs(step).sum(axis=1) == 1)
        self.stuck = np.where(moved, 0, self.stuck + 1)
        self.last_dir = np.where(moved, _direction_of(step), -1)
        self.last_pos = world.pos.copy()
        targets = self._queue_targets(world)
        self._update_assignments(world, targets)

        mask = world.action_mask()
        actions = _no_op(mask)
        free = ~world.queued
        has_queue = free & (self.target >= 0)
        goal = np.zeros((n, 2), dtype=np.int64)
        goal[has_queue] = targets[self.target[has_queue]]
        spreading = free & (self.target == SPREAD)
        goal[spreading] = self.spread_cell[spreading]
        field_of = np.zeros(n, dtype=np.int64)
        for a in np.flatnonzero(has_queue | spreading):
            field_of[a] = self._field(goal[a])

        offset = goal - world.pos
        near = has_queue & (np.abs(offset).sum(axis=1) <= 1)
        settled = np.zeros(n, dtype=bool)  # agents whose action is decided next to their target
        for a in np.flatnonzero(near):
            actions[a], settled[a] = self._join_or_step(world, a, offset[a], mask[a])
        arrived = spreading & (np.abs(offset).sum(axis=1) == 0)
        holding = self._hold_at_gate(world, has_queue & ~near)
        waiting = (near & settled) | arrived | holding | world.queued
        movers = np.flatnonzero((has_queue | spreading) & ~waiting & ~near)
        if movers.size:
            plan_moves(
                movers, world.pos, field_of, self._field_array, self._passable, world.agent_at,
                self._priority(world, holding), world.queued, waiting, self.stuck, self.last_dir,
                self.horizon, SIDESTEP_SLACK, self.stuck_limit, int(world.t % 4), actions,
            )
        return actions.astype(np.int64)

    def _join_or_step(self, world, agent: int, offset: np.ndarray, mask: np.ndarray) -> tuple[int, bool]:
        """Action of an agent on or next to its target cell, and whether it waits there.

        JOIN takes the nearest joinable queue (SPEC §1), which may be a neighbouring queue
        rather than the target: the agent then steps onto the target cell first.
        """
        row, col = world.pos[agent]
        outcome, q = find_join(
            agent, row, col, world.load[agent] > 0, world.entry_owner, world.agent_at, world.queue_is_cache,
            world.queue_resource, world.resource_remaining, world.queue_count, world.load_full,
        )
        if outcome == JOIN_OK and q == self.target[agent]:
            return JOIN, True
        if offset.any():
            step = int(_direction_of(offset[None, :])[0])
            if world.agent_at[row + offset[0], col + offset[1]] < 0:
                return step, False
        # Wait. JOIN succeeds once the entry's occupant leaves, unless it would pick another queue.
        return (JOIN if outcome != JOIN_OK else int(_no_op(mask[None, :])[0])), True


def _direction_of(step: np.ndarray) -> np.ndarray:
    """Direction index of unit (row, col) steps; meaningless for other rows."""
    return np.where(step[:, 0] == -1, 0, np.where(step[:, 1] == 1, 1, np.where(step[:, 0] == 1, 2, 3)))


def _no_op(mask: np.ndarray) -> np.ndarray:
    """An action that changes nothing: a move into a blocked cell, else JOIN when it is invalid
    (a JOIN that is valid would join, so it is the last resort)."""
    blocked = ~mask[:, :4]
    return np.where(blocked.any(axis=1), blocked.argmax(axis=1), JOIN).astype(np.int64)
