"""Cardinality-MR baseline (Hoff et al. 2010, adapted to many resources; SPEC §7).

Agents are walkers or beacons. Beacons stand still and relay hop counts to the nest and to
every resource they have heard of; walkers forage using what they see and the beacons they
hear. Communication is local: the policy object holds the beacon table only because agents of
one batch share a process, and each agent reads only the beacons within ``comm_radius``. The
choices where SPEC §7 and the reference code are silent, and why there is no reference variant,
are in docs/baselines.md.
"""

from __future__ import annotations

import numpy as np

from formic_agent.policy import AgentBatch, Policy
from formic_world.geometry import DIRECTION_DELTAS, JOIN, nest_cache_cells
from formic_world.observation import (
    CH_BLOCKED,
    CH_CACHE_ENTRY,
    CH_CACHE_QUEUED,
    CH_RESOURCE_ENTRY,
    CH_RESOURCE_QUEUED,
)

UNKNOWN = np.int32(1 << 20)  # hop count of a target the beacon has no route to
_FAR = 1 << 30


class CardinalityPolicy(Policy):
    """Walkers and beacons (Cardinality-MR)."""

    name = "cardinality"
    shares_team_memory = True

    def __init__(
        self,
        conversion_probability: float = 0.3,
        count_radius: int = 4,
        comm_radius: int = 5,
        min_beacons: int = 5,
        explore_probability: float = 0.5,
    ) -> None:
        self.conversion_probability = conversion_probability
        self.count_radius = count_radius
        self.comm_radius = comm_radius
        self.min_beacons = min_beacons
        self.explore_probability = explore_probability
        self.reset(0, 0)

    # ------------------------------------------------------------------ memory
    def reset(self, n_agents: int, seed: int) -> None:
        self.rng = np.random.default_rng([seed, 31])
        self.n = n_agents
        self.is_beacon = np.zeros(n_agents, dtype=bool)
        self.pos = np.zeros((n_agents, 2), dtype=np.int64)
        self.nest_hop = np.full(n_agents, UNKNOWN, dtype=np.int32)
        self.res_hop = np.full((n_agents, 8), UNKNOWN, dtype=np.int32)
        self.res_dead = np.zeros((n_agents, 8), dtype=bool)
        self.sees_nest = np.zeros(n_agents, dtype=bool)  # latest perceptions, for the hop update
        self.sees_res = np.zeros((n_agents, 8), dtype=bool)
        self.sees_gone = np.zeros((n_agents, 8), dtype=bool)
        self.resource_cells = np.zeros((0, 2), dtype=np.int64)
        self._resource_index: dict[tuple[int, int], int] = {}
        self.pursued = np.full(n_agents, -1, dtype=np.int64)
        self.heading = self.rng.integers(0, 4, size=n_agents)
        self.last_move = np.full(n_agents, -1, dtype=np.int64)
        self.prev_load = np.zeros(n_agents)
        self.hop_step = -1

    def forget(self, agent_ids: np.ndarray) -> None:
        ids = np.asarray(agent_ids)
        self.is_beacon[ids] = False
        self._clear_hops(ids)
        self.pursued[ids] = -1
        self.heading[ids] = self.rng.integers(0, 4, size=len(ids))
        self.last_move[ids] = -1
        self.prev_load[ids] = 0.0

    def _clear_hops(self, ids) -> None:
        self.nest_hop[ids] = UNKNOWN
        self.res_hop[ids] = UNKNOWN
        self.res_dead[ids] = False

    def _register(self, cells: np.ndarray) -> None:
        """Give newly seen resource cells a column in the hop table."""
        for cell in map(tuple, cells.tolist()):
            if cell in self._resource_index:
                continue
            k = len(self._resource_index)
            self._resource_index[cell] = k
            self.resource_cells = np.vstack([self.resource_cells, np.array([cell], dtype=np.int64)])
            if k == self.res_hop.shape[1]:  # full: double the columns
                self.res_hop = np.pad(self.res_hop, ((0, 0), (0, k)), constant_values=UNKNOWN)
                for name in ("res_dead", "sees_res", "sees_gone"):
                    setattr(self, name, np.pad(getattr(self, name), ((0, 0), (0, k))))

    # -------------------------------------------------------------- perception
    def _perceive(self, batch: AgentBatch) -> np.ndarray:
        """Learn resources in view; record what each agent sees. Returns (B, V, V) resource cells."""
        obs = batch.observations
        b, _, v, _ = obs.shape
        r = v // 2
        blocked = obs[:, CH_BLOCKED] > 0
        queue_marks = (obs[:, CH_RESOURCE_ENTRY] > 0) | (obs[:, CH_RESOURCE_QUEUED] > 0)
        marked = np.pad(queue_marks, ((0, 0), (2, 2), (2, 2)))
        resource = np.zeros_like(blocked)
        for dr, dc in DIRECTION_DELTAS:
            one = marked[:, 2 + dr: 2 + dr + v, 2 + dc: 2 + dc + v]
            two = marked[:, 2 + 2 * dr: 2 + 2 * dr + v, 2 + 2 * dc: 2 + 2 * dc + v]
            resource |= blocked & one & two
        height, width = batch.world_shape
        k, i, j = np.nonzero(resource)
        cells = np.stack([batch.positions[k, 0] + i - r, batch.positions[k, 1] + j - r], axis=1)
        inside = (cells[:, 0] >= 0) & (cells[:, 0] < height) & (cells[:, 1] >= 0) & (cells[:, 1] < width)
        nest = np.array(nest_cache_cells(height, width))
        not_nest = ~(cells[:, None, :] == nest[None]).all(axis=2).any(axis=1)
        keep = inside & not_nest
        resource[k[~keep], i[~keep], j[~keep]] = False
        self._register(cells[keep])

        ids = batch.agent_ids
        rel = self.resource_cells[None, :, :] - batch.positions[:, None, :] + r  # (B, K, 2)
        in_view = ((rel >= 0) & (rel < v)).all(axis=2)
        rr, cc = np.clip(rel[..., 0], 0, v - 1), np.clip(rel[..., 1], 0, v - 1)
        rows = np.arange(b)[:, None]
        n_known = len(self.resource_cells)
        self.sees_res[ids, :n_known] = in_view & resource[rows, rr, cc]
        self.sees_gone[ids, :n_known] = in_view & ~blocked[rows, rr, cc]
        self.sees_nest[ids] = np.abs(nest[None] - batch.positions[:, None]).max(axis=2).min(axis=1) <= r
        return resource

    # -------------------------------------------------------------- hop counts
    def _neighbours(
        self, where: np.ndarray, beacons: np.ndarray, radius: int, exclude: np.ndarray
    ) -> np.ndarray:
        """(len(where), len(beacons)) bool: beacon within ``radius`` (Chebyshev), not itself."""
        gap = np.abs(where[:, None, :] - self.pos[beacons][None, :, :]).max(axis=2)
        return (gap <= radius) & (exclude[:, None] != beacons[None, :])

    def _relay(self, ids: np.ndarray, beacons: np.ndarray) -> None:
        """Set the hop counts and depletion marks of ``ids`` from what they see and hear of
        ``beacons`` (all read from the table before any is written)."""
        heard = self._neighbours(self.pos[ids], beacons, self.comm_radius, ids)  # (I, M)
        k = len(self.resource_cells)
        nest = np.where(heard, self.nest_hop[beacons][None, :], UNKNOWN).min(axis=1, initial=UNKNOWN)
        nest = np.where(self.sees_nest[ids], 1, np.minimum(nest + 1, UNKNOWN))
        hops = np.where(heard[:, :, None], self.res_hop[beacons][None, :, :k], UNKNOWN)
        hops = hops.min(axis=1, initial=UNKNOWN)
        hops = np.where(self.sees_res[ids, :k], 1, np.minimum(hops + 1, UNKNOWN))
        dead = (heard.astype(np.int32) @ self.res_dead[beacons, :k].astype(np.int32)) > 0
        dead = (dead | self.sees_gone[ids, :k]) & ~self.sees_res[ids, :k]
        limit = self.n  # a real chain has at most one hop per beacon: more means a stale loop
        nest[nest > limit] = UNKNOWN
        hops[(hops > limit) | dead] = UNKNOWN
        self.nest_hop[ids], self.res_hop[ids, :k], self.res_dead[ids, :k] = nest, hops, dead

    # -------------------------------------------------------------------- roles
    def _nest_beacons_near(self, agents: np.ndarray) -> np.ndarray:
        """How many beacons that know the way to the nest each agent counts (9x9, not itself)."""
        beacons = np.flatnonzero(self.is_beacon & (self.nest_hop < UNKNOWN))
        return self._neighbours(self.pos[agents], beacons, self.count_radius, agents).sum(axis=1)

    def _change_roles(self, batch: AgentBatch, at_queue: np.ndarray) -> None:
        """Walkers that lost the beacons become beacons; crowded beacons may walk again.

        Decided one agent at a time in a random order, each seeing the changes before it."""
        ids = batch.agent_ids
        count = self._nest_beacons_near(ids)
        beacon = self.is_beacon[ids]
        candidates = ~batch.queued & ((beacon & (count > 2)) | (~beacon & ~at_queue & (count < 2)))
        rows = np.flatnonzero(candidates)
        for row in rows[self.rng.permutation(len(rows))]:
            agent = ids[row]
            count = int(self._nest_beacons_near(np.array([agent]))[0])
            if self.is_beacon[agent]:
                if count > 2 and self.rng.random() < self.conversion_probability:
                    self.is_beacon[agent] = False
                    self._clear_hops(agent)
            elif count < 2:
                self._relay(np.array([agent]), np.flatnonzero(self.is_beacon))
                self.is_beacon[agent] = True

    # ---------------------------------------------------------------- walkers
    def _choose_resources(self, batch: AgentBatch, rows: np.ndarray, heard: np.ndarray,
                          beacons: np.ndarray) -> None:
        """Empty walkers leaving the nest pick a known resource: weight 1/hops + 0.5; explore
        with probability 0.5 when fewer than ``min_beacons`` beacons are in view. ``heard``:
        (B, M), which of the ``beacons`` each batch agent hears."""
        k = len(self.resource_cells)
        for row in rows:
            agent = batch.agent_ids[row]
            hops = self.res_hop[beacons[heard[row]], :k]
            best = hops.min(axis=0, initial=UNKNOWN)
            known = np.flatnonzero(best < UNKNOWN)
            if len(known) == 0:
                self.pursued[agent] = -1
                continue
            weight = 1.0 / best[known] + 0.5
            p = weight / weight.sum()
            if heard[row].sum() < self.min_beacons:
                p = np.append(p * (1 - self.explore_probability), self.explore_probability)
                known = np.append(known, -1)
            self.pursued[agent] = known[self.rng.choice(len(known), p=p)]

    def _walker_targets(self, batch: AgentBatch, resource: np.ndarray, heard: np.ndarray,
                        beacons: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Offset (dr, dc) each walker heads for and whether it has one (else it explores):
        a visible queue entry of the type it needs, else the needed cells, else the beacon
        that hears the smallest hop count to its goal."""
        obs = batch.observations
        b, _, v, _ = obs.shape
        r = v // 2
        loaded = batch.loads > 0
        grid_r, grid_c = np.mgrid[0:v, 0:v] - r
        square = (grid_r**2 + grid_c**2)[None]
        offset = np.zeros((b, 2), dtype=np.int64)
        found = np.zeros(b, dtype=bool)

        def take(mask: np.ndarray, select: np.ndarray) -> None:
            cost = np.where(mask, square, _FAR).reshape(b, -1)
            best = cost.argmin(axis=1)
            ok = select & ~found & (cost[np.arange(b), best] < _FAR)
            offset[ok] = np.stack([grid_r.ravel()[best[ok]], grid_c.ravel()[best[ok]]], axis=1)
            found[ok] = True

        entries = np.where(loaded[:, None, None], obs[:, CH_CACHE_ENTRY], obs[:, CH_RESOURCE_ENTRY]) > 0
        take(entries, np.ones(b, dtype=bool))
        height, width = batch.world_shape
        nest = np.zeros((b, v, v), dtype=bool)
        for cr, cc in nest_cache_cells(height, width):
            rel_r, rel_c = cr - batch.positions[:, 0] + r, cc - batch.positions[:, 1] + r
            ok = (rel_r >= 0) & (rel_r < v) & (rel_c >= 0) & (rel_c < v)
            nest[np.flatnonzero(ok), rel_r[ok], rel_c[ok]] = True
        take(nest, loaded)
        take(resource | (obs[:, CH_RESOURCE_QUEUED] > 0), ~loaded)
        if len(beacons):
            pursued = self.pursued[batch.agent_ids]
            res_hop = self.res_hop[beacons][:, np.maximum(pursued, 0)].T  # (B, M)
            res_hop = np.where(pursued[:, None] >= 0, res_hop, UNKNOWN)
            hop = np.where(loaded[:, None], self.nest_hop[beacons][None, :], res_hop)
            rel = self.pos[beacons][None, :, :] - batch.positions[:, None, :]  # (B, M, 2)
            fewest_then_nearest = hop.astype(np.int64) * 10_000 + (rel**2).sum(axis=2)
            key = np.where(heard & (hop < UNKNOWN), fewest_then_nearest, _FAR)
            best = key.argmin(axis=1)
            ok = ~found & (key[np.arange(b), best] < _FAR)
            offset[ok] = rel[np.flatnonzero(ok), best[ok]]
            found[ok] = True
        return offset, found

    def _steer(self, offset: np.ndarray, mask: np.ndarray, last: np.ndarray) -> np.ndarray:
        """The valid move best aligned with ``offset``, not undoing the last move if avoidable;
        -1 when no move is valid."""
        dots = offset @ DIRECTION_DELTAS.T  # (B, 4)
        moves = mask[:, :4]
        reverse = (last[:, None] >= 0) & (np.arange(4) == (last[:, None] + 2) % 4)
        allowed = moves & ~reverse
        allowed[~allowed.any(axis=1)] = moves[~allowed.any(axis=1)]
        choice = np.where(allowed, dots, -_FAR).argmax(axis=1)
        return np.where(allowed.any(axis=1), choice, -1)

    def _explore(self, agents: np.ndarray, mask: np.ndarray) -> np.ndarray:
        """Persistent random heading; a blocked heading is replaced by a random valid one."""
        actions = np.full(len(agents), -1, dtype=np.int64)
        for row, agent in enumerate(agents):
            valid = np.flatnonzero(mask[row, :4])
            if len(valid) == 0:
                continue
            if not mask[row, self.heading[agent]]:
                last = self.last_move[agent]
                forward = valid[valid != (last + 2) % 4] if last >= 0 else valid
                options = forward if len(forward) else valid
                self.heading[agent] = options[self.rng.integers(len(options))]
            actions[row] = self.heading[agent]
        return actions

    # ------------------------------------------------------------------ acting
    def act(self, batch: AgentBatch) -> np.ndarray:
        ids = batch.agent_ids
        b = len(ids)
        if b == 0:
            return np.zeros(0, dtype=np.int64)
        if ids.max() >= self.n:
            raise ValueError(f"agent id {ids.max()} but reset() was given {self.n} agents")
        mask = batch.action_mask
        obs = batch.observations
        r = obs.shape[-1] // 2
        self.pos[ids] = batch.positions
        resource = self._perceive(batch)
        if batch.step != self.hop_step:  # one synchronous relay round over every beacon
            self.hop_step = batch.step
            beacons = np.flatnonzero(self.is_beacon)
            if len(beacons):
                self._relay(beacons, beacons)
        queue_channels = [CH_RESOURCE_ENTRY, CH_CACHE_ENTRY, CH_RESOURCE_QUEUED, CH_CACHE_QUEUED]
        around = obs[:, queue_channels, r - 1: r + 2, r - 1: r + 2]
        self._change_roles(batch, at_queue=(around > 0).any(axis=(1, 2, 3)))

        actions = np.full(b, JOIN, dtype=np.int64)
        free = ~batch.queued
        blocked_moves = ~mask[:, :4]
        beacon = free & self.is_beacon[ids]
        stranded = beacon & ~blocked_moves.any(axis=1) & mask[:, JOIN]
        self.is_beacon[ids[stranded]] = False  # no action would leave it in place: walk again
        self._clear_hops(ids[stranded])
        beacon &= ~stranded
        stay = blocked_moves[beacon]
        actions[beacon] = np.where(stay.any(axis=1), stay.argmax(axis=1), JOIN)

        walker = free & ~beacon
        beacons = np.flatnonzero(self.is_beacon)
        heard = self._neighbours(batch.positions, beacons, self.comm_radius, ids)  # (B, M)
        pursued = self.pursued[ids]
        column = np.maximum(pursued, 0)
        lost = (pursued >= 0) & (
            self.sees_gone[ids, column] | (heard & self.res_dead[beacons][:, column].T).any(axis=1)
        )
        choose = walker & (batch.loads <= 0) & ((self.prev_load[ids] > 0) | lost)  # left the nest, or lost
        self._choose_resources(batch, np.flatnonzero(choose), heard, beacons)
        offset, found = self._walker_targets(batch, resource, heard, beacons)
        joining = walker & mask[:, JOIN]
        move = self._steer(offset, mask, self.last_move[ids])
        explorers = np.flatnonzero(walker & ~joining & ~found)
        move[explorers] = self._explore(ids[explorers], mask[explorers])
        on_entry = walker & found & (np.abs(offset).sum(axis=1) == 0)  # entry held by another agent
        moving = walker & ~joining & ~on_entry & (move >= 0)
        actions[moving] = move[moving]
        self.last_move[ids] = np.where(moving, move, np.where(walker & ~on_entry, -1, self.last_move[ids]))
        self.prev_load[ids] = batch.loads
        return actions
