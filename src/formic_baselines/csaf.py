"""C-SAF and C-SAF-11: the pheromone state machine of Zedadra et al. (2016) as adapted by the
ForMIC paper (SPEC §7), behind the common :class:`Policy` interface.

Agents search (spiralling out, marking cells), return loaded down the search gradient while
colouring a trail, orbit the nest to its caches, then leave, climb a trail or erase a dead one.
Both pheromones are C-SAF's own, on a :class:`PheromoneGround` the team shares. The states,
the choices left open by the paper, the SPEC and the reference code, and the reference variant
(``reference=True``: ``csaf-ref``, ``csaf11-ref``, which runs C-SAF as the authors' code did)
are described in docs/baselines.md.
"""

from __future__ import annotations

import numpy as np

from formic_agent.policy import AgentBatch, Policy
from formic_world.geometry import DIRECTION_DELTAS, JOIN, nest_cache_cells, nest_centre
from formic_world.observation import (
    CH_BLOCKED,
    CH_CACHE_ENTRY,
    CH_CACHE_QUEUED,
    CH_CARRYING_AGENTS,
    CH_EMPTY_AGENTS,
    CH_RESOURCE_ENTRY,
    CH_RESOURCE_QUEUED,
)

_DR = tuple(DIRECTION_DELTAS[:, 0].tolist())
_DC = tuple(DIRECTION_DELTAS[:, 1].tolist())
NORTH, EAST, SOUTH, WEST = range(4)
NEW, SEARCH, RETURN, ORBIT, LEAVE, CLIMB, ERASE = range(7)
NO_TRAIL = np.iinfo(np.int32).max
_EPS = 1e-9
_NEVER = np.iinfo(np.int64).max
_REF_CORNER = 5  # the reference variant's misread cell: offset (+5, +5), its 11x11 view's corner


class PheromoneGround:
    """C-SAF's marks on the ground, shared by the whole team (they are physical)."""

    def __init__(self, shape: tuple[int, int], decay: float):
        self.shape = shape
        self.decay = decay
        self.marked_at = np.full(shape, -1, dtype=np.int64)  # search pheromone: step of first mark
        self.trails: dict[int, np.ndarray] = {}  # resource key -> hops from the resource
        self.trail_count = np.zeros(shape, dtype=np.int32)  # trail layers present in each cell
        self.blackout_until = -1  # no mark is laid before this step (a wipeout)

    def search_values(self, step: int) -> np.ndarray:
        """Search-pheromone concentration at ``step``: decay**(age), 0 where never marked."""
        marked = self.marked_at >= 0
        return np.where(marked, self.decay ** np.maximum(step - self.marked_at, 0), 0.0)

    def mark(self, row: int, col: int, step: int) -> None:
        if self.marked_at[row, col] < 0:
            self.marked_at[row, col] = step

    def colour(self, key: int, row: int, col: int, hops: int) -> None:
        layer = self.trails.get(key)
        if layer is None:
            layer = self.trails[key] = np.full(self.shape, NO_TRAIL, dtype=np.int32)
        if layer[row, col] == NO_TRAIL:
            self.trail_count[row, col] += 1
        layer[row, col] = min(layer[row, col], hops)

    def erase(self, key: int, row: int, col: int) -> None:
        layer = self.trails.get(key)
        if layer is not None and layer[row, col] != NO_TRAIL:
            layer[row, col] = NO_TRAIL
            self.trail_count[row, col] -= 1

    def layers_at(self, row: int, col: int) -> list[int]:
        if self.trail_count[row, col] == 0:
            return []
        return [key for key, layer in self.trails.items() if layer[row, col] != NO_TRAIL]

    def clear(self) -> None:
        self.marked_at[:] = -1
        self.trails.clear()
        self.trail_count[:] = 0


class _Agent:
    """One agent's sensing this step (read-only helpers over its observation window)."""

    __slots__ = ("i", "row", "col", "obs", "valid", "join_ok", "centre", "height", "width")

    def __init__(self, i, row, col, obs, mask, height, width):
        self.i = i
        self.row, self.col = row, col
        self.obs = obs
        self.valid = [bool(v) for v in mask[:4]]
        self.join_ok = bool(mask[JOIN])
        self.centre = obs.shape[-1] // 2
        self.height, self.width = height, width

    def cell(self, d: int) -> tuple[int, int]:
        return self.row + _DR[d], self.col + _DC[d]

    def inside(self, r: int, c: int) -> bool:
        return 0 <= r < self.height and 0 <= c < self.width

    def sees(self, channel: int) -> bool:
        """Whether ``channel`` shows anything in the 3x3 view."""
        k = self.centre
        return bool(self.obs[channel, k - 1:k + 2, k - 1:k + 2].any())

    def walled(self, d: int) -> bool:
        """Whether the move ``d`` runs into a wall (outside, an obstacle, a resource or a cache)."""
        r, c = self.cell(d)
        return not self.inside(r, c) or self.obs[CH_BLOCKED, self.centre + _DR[d], self.centre + _DC[d]] > 0

    def around(self, grid: np.ndarray, outside: int) -> list[int]:
        """``grid`` at the four neighbouring cells (N, E, S, W), ``outside`` beyond the world."""
        return [int(grid[self.cell(d)]) if self.inside(*self.cell(d)) else outside for d in range(4)]

    def nearest(self, channel: int, radius: int) -> list[list[int]]:
        """Offsets of the nearest cells of ``channel`` within ``radius`` that no agent stands on
        (all that are equally near; none when there is no such cell)."""
        k = self.centre
        window = (slice(k - radius, k + radius + 1),) * 2
        free = (self.obs[channel][window] > 0) & (self.obs[CH_EMPTY_AGENTS][window] == 0)
        free &= self.obs[CH_CARRYING_AGENTS][window] == 0
        free[radius, radius] = False
        offsets = np.argwhere(free) - radius
        dist = np.abs(offsets).sum(axis=1)
        return offsets[dist == dist.min()].tolist() if len(offsets) else []

    def stay(self) -> int:
        """An action that leaves the agent where it is: a move into a wall, else a null JOIN."""
        return next((d for d in range(4) if self.walled(d)), JOIN)


def _clockwise(offset) -> float:
    """Bearing of an offset clockwise from north: N, NE, E, SE, S, SW, W, NW (the reference
    variant's fixed tie order, which on the four neighbours is N, E, S, W)."""
    dr, dc = offset
    return float(np.arctan2(dc, -dr) % (2 * np.pi))


class CSAFPolicy(Policy):
    """C-SAF (``view=3``) or C-SAF-11 (``view=11``), see docs/baselines.md; ``reference``
    selects the reference variant (fixed tie order, blocked agents never yield)."""

    shares_team_memory = True  # the marks of the whole team live on one ground

    def __init__(
        self,
        view: int = 3,
        search_decay: float = 0.925,
        wipeout_steps: int = 100,
        leave_patience: int = 24,
        nest_radius: int = 2,
        reference: bool = False,
    ):
        if view < 3 or view % 2 == 0:
            raise ValueError(f"view must be odd and >= 3, got {view}")
        self.view = view
        self.reference = reference
        self.name = ("csaf" if view == 3 else f"csaf{view}") + ("-ref" if reference else "")
        self.search_decay = search_decay
        self.wipeout_steps = wipeout_steps
        self.leave_patience = leave_patience
        self.nest_radius = nest_radius
        self.reset(0, 0)

    # ---------------------------------------------------------------- lifecycle
    _MEMORY = ("state", "heading", "free_load", "queued_since", "trail_key", "colouring", "hops",
               "last_pos", "counter", "went_out", "floor", "last_action")

    def reset(self, n_agents: int, seed: int) -> None:
        self.rng = np.random.default_rng([seed, 13])
        self.ground: PheromoneGround | None = None
        self.step = -1
        self._writes: list[tuple] = []  # marks laid this step, landing at the next one
        self._blackout_steps: int | None = None  # a wipe() waiting for its first step
        self.radius = self.view // 2  # how far queue entries are looked for
        self._noop = False  # the reference's no-op: the agent's next step has no way back
        self._allocate(n_agents)

    def forget(self, agent_ids: np.ndarray) -> None:
        ids = np.asarray(agent_ids, dtype=np.int64)
        self.state[ids] = NEW
        self.queued_since[ids] = False

    def wipe(self, steps: int | None = None) -> None:
        """A wipeout starts: every C-SAF mark vanishes and none is laid for ``steps`` steps
        (default ``wipeout_steps``), counted from the next step acted on. The harness calls
        this at the start of each wipeout window, before that step's ``act``."""
        if self.ground is not None:
            self.ground.clear()
        self._writes.clear()
        self._blackout_steps = self.wipeout_steps if steps is None else steps

    def _allocate(self, n: int) -> None:
        self.state = np.full(n, NEW, dtype=np.int64)
        self.heading = np.zeros(n, dtype=np.int64)
        self.free_load = np.zeros(n)  # load when last seen free
        self.queued_since = np.zeros(n, dtype=bool)  # seen queued since last free
        self.trail_key = np.full(n, -1, dtype=np.int64)  # layer coloured, climbed or erased
        self.colouring = np.zeros(n, dtype=bool)
        self.hops = np.zeros(n, dtype=np.int64)  # cells walked from the resource
        self.last_pos = np.full((n, 2), -1, dtype=np.int64)
        self.counter = np.zeros(n, dtype=np.int64)  # steps spent looking for a trail
        self.went_out = np.zeros(n, dtype=bool)  # last orbit move stepped away from the nest
        self.floor = np.full(n, _NEVER, dtype=np.int64)  # oldest search mark reached this trip
        self.last_action = np.full(n, JOIN, dtype=np.int64)  # the reference's prev_action (JOIN: none)

    def _grow(self, n: int) -> None:
        """Agent ids beyond those given to :meth:`reset` start with fresh memory."""
        old = len(self.state)
        if n > old:
            saved = {name: getattr(self, name) for name in self._MEMORY}
            self._allocate(n)
            for name, values in saved.items():
                getattr(self, name)[:old] = values

    # ---------------------------------------------------------------------- act
    def act(self, batch: AgentBatch) -> np.ndarray:
        height, width = batch.world_shape
        if self.ground is None or self.ground.shape != (height, width):
            self.ground = PheromoneGround((height, width), self.search_decay)
        if batch.step != self.step:  # a new step: last step's marks land
            for kind, *args in self._writes:
                getattr(self.ground, kind)(*args)  # PheromoneGround.mark, .colour or .erase
            self._writes.clear()
            self.step = batch.step
            if self._blackout_steps is not None:
                self.ground.blackout_until = batch.step + self._blackout_steps
                self._blackout_steps = None
        if len(batch):
            self._grow(int(np.max(batch.agent_ids)) + 1)
        self.radius = min(self.view, batch.observations.shape[-1]) // 2
        self._se_cache = nest_cache_cells(height, width)[-1]  # the nest's 2x2 is (h-1..h, w-1..w)
        actions = np.zeros(len(batch), dtype=np.int64)  # queued agents' actions are ignored
        positions = np.asarray(batch.positions).tolist()
        for k, i in enumerate(np.asarray(batch.agent_ids).tolist()):
            agent = _Agent(i, positions[k][0], positions[k][1], batch.observations[k],
                           batch.action_mask[k], height, width)
            if self.state[i] == NEW:
                self._start(agent, float(batch.loads[k]))
            if batch.queued[k]:
                self.queued_since[i] = True
                continue
            self._update_state(agent, float(batch.loads[k]))
            self._noop = False
            actions[k] = self._decide(agent)
            if actions[k] < 4:
                self.heading[i] = actions[k]
            self.last_action[i] = JOIN if self._noop else actions[k]
        if self.step < self.ground.blackout_until:
            self._writes.clear()  # nothing is laid during a wipeout
        return actions

    # -------------------------------------------------------------- transitions
    def _start(self, a: _Agent, load: float) -> None:
        """First sight of an agent: head away from the nest (diagonal ties split by id)."""
        centre_r, centre_c = nest_centre(a.height, a.width)
        dr, dc = a.row - centre_r, a.col - centre_c
        vertical = SOUTH if dr > 0 else NORTH
        horizontal = EAST if dc > 0 else WEST
        go_vertical = abs(dr) > abs(dc) or (abs(dr) == abs(dc) and a.i % 2 == 0)
        self.heading[a.i] = vertical if go_vertical else horizontal
        self.state[a.i] = SEARCH
        self.colouring[a.i] = False
        self.free_load[a.i] = load
        if load > _EPS:
            self._start_return(a, colour=False)

    def _update_state(self, a: _Agent, load: float) -> None:
        """Transitions driven by the world: a collection, a drop-off, a vanished resource."""
        i = a.i
        carrying = load > _EPS
        if load > self.free_load[i] + _EPS:  # left a resource queue with food
            # Only a full load means the resource is still there to be trailed.
            self._start_return(a, colour=load >= 1.0 - _EPS)
        elif load < self.free_load[i] - _EPS:  # unloaded at the nest
            self.state[i] = LEAVE
            self.counter[i] = 0
        elif carrying and self.state[i] not in (RETURN, ORBIT):
            self._start_return(a, colour=False)
        elif not carrying and (self.queued_since[i] or self.state[i] in (RETURN, ORBIT)):
            self.state[i] = SEARCH  # released empty (the resource is gone), or no longer loaded
        self.queued_since[i] = False
        self.free_load[i] = load

    def _start_return(self, a: _Agent, colour: bool) -> None:
        i = a.i
        self.state[i] = RETURN
        self.colouring[i] = colour
        self.trail_key[i] = a.row * a.width + a.col  # the queue's spot 0 names the resource
        self.hops[i] = 0
        self.last_pos[i] = a.row, a.col
        self.floor[i] = _NEVER

    def _decide(self, a: _Agent) -> int:
        state = self.state[a.i]
        if state in (RETURN, ORBIT):
            return self._loaded(a)
        if a.join_ok:
            return JOIN
        # C-SAF-11's camera scan for resource queues is a search rule.
        entries = a.nearest(CH_RESOURCE_ENTRY, self.radius if state == SEARCH else 1)
        if entries:
            if state == SEARCH:  # still exploring: the way to the queue joins the gradient
                self._writes.append(("mark", a.row, a.col, self.step))
            return self._toward(a, *self._choose(entries, _clockwise))
        return {CLIMB: self._climb, ERASE: self._erase, LEAVE: self._leave}.get(state, self._search)(a)

    # ------------------------------------------------------------------- search
    def _search(self, a: _Agent) -> int:
        """The search rules (also where every other rule that gives up falls back to)."""
        self.state[a.i] = SEARCH
        marked_at = self.ground.marked_at
        self._writes.append(("mark", a.row, a.col, self.step))
        stamps = a.around(marked_at, -1)
        h = self.heading[a.i]
        if marked_at[a.row, a.col] < 0 and max(stamps) < 0:
            return self._straight(a, h)  # nothing sensed around: keep going
        turns = ((h + 1) % 4, h, (h + 3) % 4) + (() if self.reference else ((h + 2) % 4,))
        for d in turns:  # right, ahead, left; the default then turns back
            if a.valid[d] and stamps[d] < 0:
                return d
        if self.reference:
            for d in range(4):  # the reference's fallback: N, E, S, W, other agents unseen
                if not a.walled(d) and stamps[d] < 0:
                    return d  # taken by an agent: the move fails, and is tried again
        own = marked_at[a.row, a.col]
        newer = [d for d in range(4) if a.valid[d] and d != (h + 2) % 4 and stamps[d] > own]
        if newer:
            return self._pick(newer, [-stamps[d] for d in newer])
        return self._straight(a, h)

    def _straight(self, a: _Agent, h: int) -> int:
        if self.reference:  # an agent ahead: wait for it; a wall: turn, N, E, S, W first
            turns = (h, min((h + 1) % 4, (h + 3) % 4), max((h + 1) % 4, (h + 3) % 4), (h + 2) % 4)
            return next((d for d in turns if not a.walled(d)), a.stay())
        if a.valid[h]:
            return h
        turns = [d for d in ((h + 1) % 4, (h + 3) % 4) if a.valid[d]]
        if turns:
            return self._choose(turns)
        return (h + 2) % 4 if a.valid[(h + 2) % 4] else a.stay()

    def _follow_trail(self, a: _Agent) -> bool:
        """Pick a trail sensed in the 3x3 view to climb (a random layer where several meet)."""
        cells = [(a.row, a.col)] + [a.cell(d) for d in range(4)]
        cells += [(a.row + dr, a.col + dc) for dr in (-1, 1) for dc in (-1, 1)]
        for r, c in cells:
            keys = a.inside(r, c) and self.ground.layers_at(r, c)
            if keys:
                self.trail_key[a.i] = self._choose(keys)
                return True
        return False

    # ------------------------------------------------------------- trail rules
    def _climb(self, a: _Agent) -> int:
        self.state[a.i] = CLIMB
        layer = self.ground.trails.get(int(self.trail_key[a.i]))
        if layer is None:
            return self._search(a)
        own = int(layer[a.row, a.col])
        hops = a.around(layer, NO_TRAIL)
        lower = [d for d in range(4) if hops[d] < own]
        movable = [d for d in lower if a.valid[d]]
        if movable:
            return self._pick(movable, [hops[d] for d in movable])
        if a.sees(CH_RESOURCE_QUEUED):  # at the queue, but no entry in reach: try elsewhere
            return self._search(a)
        if lower:  # the way up is taken by another agent
            return self._retry(a, lower, hops) if self.reference else self._sidestep(a)
        if own == NO_TRAIL:
            diagonal = [(dr, dc) for dr in (-1, 1) for dc in (-1, 1)
                        if a.inside(a.row + dr, a.col + dc) and layer[a.row + dr, a.col + dc] != NO_TRAIL]
            if diagonal:
                return self._toward(a, *self._choose(diagonal, _clockwise))
            return self._search(a)  # lost the trail
        return self._erase(a)  # the top of the trail, and no resource there

    def _erase(self, a: _Agent) -> int:
        self.state[a.i] = ERASE
        key = int(self.trail_key[a.i])
        layer = self.ground.trails.get(key)
        own = NO_TRAIL if layer is None else int(layer[a.row, a.col])
        if own == NO_TRAIL:
            return self._search(a)
        self._writes.append(("erase", key, a.row, a.col))
        hops = a.around(layer, NO_TRAIL)
        down = [d for d in range(4) if own < hops[d] < NO_TRAIL]
        if not down:  # the bottom of the trail
            return self._search(a)
        d = self._pick(down, [hops[d] for d in down])
        if self.reference and not a.walled(d):
            return d  # taken by another agent: wait for it
        return d if a.valid[d] else a.stay()

    # ------------------------------------------------------------------ loaded
    def _loaded(self, a: _Agent) -> int:
        i = a.i
        if self.colouring[i]:  # the trail runs from the resource to where the nest is reached
            if a.row != self.last_pos[i, 0] or a.col != self.last_pos[i, 1]:
                self.hops[i] += 1
                self.last_pos[i] = a.row, a.col
            self._writes.append(("colour", int(self.trail_key[i]), a.row, a.col, int(self.hops[i])))
        if a.join_ok:
            return JOIN
        # The reference's loaded agents scan for no cache entry: they join where JOIN is valid.
        entries = [] if self.reference else a.nearest(CH_CACHE_ENTRY, self.radius)
        if entries:
            return self._toward(a, *self._choose(entries, _clockwise))
        if self.state[i] == RETURN:
            if self._ring(a.row, a.col) > self.nest_radius and not a.sees(CH_CACHE_QUEUED):
                return self._descend_reference(a) if self.reference else self._descend(a)
            self.state[i] = ORBIT
            self.colouring[i] = False
            self.went_out[i] = False
        return self._orbit(a)

    def _descend(self, a: _Agent) -> int:
        """Down the search-pheromone gradient, only ever to marks older than the oldest one
        reached on this trip (so a local minimum cannot trap the agent in a loop); one step
        straight home where the gradient gives no such way down."""
        i = a.i
        own = int(self.ground.marked_at[a.row, a.col])
        if 0 <= own < self.floor[i]:
            self.floor[i] = own
        stamps = a.around(self.ground.marked_at, -1)
        lower = [d for d in range(4) if 0 <= stamps[d] < self.floor[i]]
        movable = [d for d in lower if a.valid[d]]
        if movable:
            return self._pick(movable, [stamps[d] for d in movable])
        if lower:
            return self._retry(a, lower, stamps) if self.reference else self._sidestep(a)
        return self._home(a)

    def _descend_reference(self, a: _Agent) -> int:
        """The reference's way home: to the neighbour with the oldest mark (the weakest
        search pheromone) among the marked ones other than straight back (the move opposite
        to its last action, none after a JOIN or a no-op), the first of them no agent stands
        on; when the two weakest free ones are equal, the move towards the nest centre
        instead. All taken: wait for the weakest. Nothing marked but the way back: a no-op
        (the way back is allowed next step); nothing marked at all: straight home."""
        i = a.i
        stamps = a.around(self.ground.marked_at, -1)
        last = int(self.last_action[i])
        back = (last + 2) % 4 if last < 4 else -1
        marked = sorted((d for d in range(4) if stamps[d] >= 0 and d != back), key=lambda d: (stamps[d], d))
        free = [d for d in marked if a.valid[d]]
        if free:
            if len(free) > 1 and stamps[free[0]] == stamps[free[1]]:
                return self._nest_vector_move(a)
            return free[0]
        if marked:
            return marked[0]  # taken (or a wall): the move fails and the agent waits
        if back >= 0 and stamps[back] >= 0:
            self._noop = True
            return a.stay()
        return self._home(a)

    def _nest_vector_move(self, a: _Agent) -> int:
        """The reference's move best aligned with the vector to the world's centre
        ((H-1)/2, (W-1)/2), ties N, E, S, W; it may be a wall or taken (then it fails)."""
        dr, dc = (a.height - 1) / 2 - a.row, (a.width - 1) / 2 - a.col
        return int(np.argmax([-dr, dc, dr, -dc]))

    def _home(self, a: _Agent) -> int:
        """One step straight towards the nest (odometry)."""
        h, w = self._se_cache
        dr = min(max(a.row, h - 1), h) - a.row
        dc = min(max(a.col, w - 1), w) - a.col
        return self._toward(a, dr, dc)

    def _ring(self, row: int, col: int) -> int:
        """Chebyshev distance from the 2x2 nest (1: the cells around the caches)."""
        h, w = self._se_cache
        return max(h - 1 - row, row - h, w - 1 - col, col - w, 0)

    def _orbit(self, a: _Agent) -> int:
        """Circle the nest clockwise with the caches and the cache queues on the right: the
        move towards the nest when it gets closer, else around, else away from it."""
        i = a.i
        h, w = self._se_cache
        r, c = a.row, a.col
        if r <= h - 2 and c <= w:
            around = EAST
        elif c >= w + 1 and r <= h:
            around = SOUTH
        elif r >= h + 1 and c >= w - 1:
            around = WEST
        else:
            around = NORTH
        inward, outward = (around + 1) % 4, (around + 3) % 4
        ring = self._ring(r, c)
        order = [around, outward]
        ir, ic = a.cell(inward)
        if not self.went_out[i] and self._ring(ir, ic) < ring:
            order.insert(0, inward)
        for d in order:
            if a.valid[d]:
                self.went_out[i] = d == outward
                return d
        # Boxed in: the reference waits for the first of those moves to clear; the default
        # makes room (it may stand on a queue's spot 0).
        return self._retry(a, order) if self.reference else self._sidestep(a)

    def _leave(self, a: _Agent) -> int:
        i = a.i
        if self.reference and self.counter[i] == 0 and a.centre >= _REF_CORNER:
            # The reference checks the cell behind a just-unloaded agent with the heading of
            # its JOIN (none), which reads the view's corner 5 south, 5 east: it waits while
            # an agent stands there.
            k = a.centre + _REF_CORNER
            if a.obs[CH_EMPTY_AGENTS, k, k] > 0 or a.obs[CH_CARRYING_AGENTS, k, k] > 0:
                return a.stay()
        if self._follow_trail(a):
            return self._climb(a)
        self.counter[i] += 1
        if self.counter[i] > self.leave_patience:
            return self._search(a)
        return self._orbit(a)

    # ------------------------------------------------------------------ moves
    def _toward(self, a: _Agent, dr: int, dc: int) -> int:
        """A move that brings the agent closer to the offset (dr, dc), larger axis first."""
        vertical = SOUTH if dr > 0 else NORTH
        horizontal = EAST if dc > 0 else WEST
        options = []
        if abs(dr) > abs(dc):
            options = [vertical] + ([horizontal] if dc else [])
        elif abs(dc) > abs(dr):
            options = [horizontal] + ([vertical] if dr else [])
        elif dr and self.reference:
            options = sorted((vertical, horizontal))
        elif dr:
            options = [vertical, horizontal] if self.rng.random() < 0.5 else [horizontal, vertical]
        for d in options:
            if a.valid[d]:
                return d
        return self._retry(a, options) if self.reference else self._sidestep(a)

    def _sidestep(self, a: _Agent) -> int:
        """The wanted cell is taken: wait or step aside at random (agents never lock)."""
        moves = [d for d in range(4) if a.valid[d]]
        if not moves or self.rng.random() < 0.5:
            return a.stay()
        return self._choose(moves)

    def _pick(self, options: list[int], costs: list[int]) -> int:
        """The cheapest option, ties at random (the reference variant: N, E, S, W first)."""
        best = min(costs)
        return self._choose([d for d, cost in zip(options, costs) if cost == best])

    def _choose(self, options: list, key=None):
        """One of ``options`` at random; the reference variant's fixed order takes the smallest
        (by ``key``: :func:`_clockwise` for offsets)."""
        return min(options, key=key) if self.reference else options[self.rng.integers(len(options))]

    def _retry(self, a: _Agent, wanted: list[int], costs: list[int] | None = None) -> int:
        """The reference variant's answer to a blocked way: the first wanted move (in the
        given order, or the cheapest by ``costs[d]``, then N, E, S, W) that is not into a
        wall, although another agent stands there: the move fails and the agent waits, its
        heading kept, until the cell clears. Only when every wanted move is into a wall: the
        first free move in N, E, S, W order, else stay."""
        if costs is not None:
            wanted = sorted(wanted, key=lambda d: (costs[d], d))
        moves = [d for d in wanted if not a.walled(d)] + [d for d in range(4) if a.valid[d]]
        return moves[0] if moves else a.stay()


class CSAF11Policy(CSAFPolicy):
    """C-SAF-11: C-SAF with the 11x11 view (the paper's fair-comparison variant)."""

    def __init__(self, **kwargs):
        super().__init__(view=11, **kwargs)
