"""C-SAF and C-SAF-11: the pheromone state machine of Zedadra et al. (2016) as adapted by the
ForMIC paper (SPEC §7), behind the common :class:`Policy` interface.

Each agent is a state machine over its local view (3x3 for C-SAF, the 11x11 window for
C-SAF-11), its odometry (position, hence the nest at the world's centre), its load and queued
flag, and two pheromones of C-SAF's own that the whole team reads and writes on the ground
(:class:`PheromoneGround`, owned by the policy object because the marks are physical). They
are not the world's ForMIC pheromone (observation channel 7), which C-SAF never reads.

- ``SEARCH``: mark every cell on its first visit with the *search* pheromone; turn right into
  an unmarked cell if possible, else go straight, else left (a spiral around the explored
  region, so the nearest resources are found first); when all three are marked, climb to the
  most recently marked neighbour (the frontier). Join a resource queue when JOIN is valid,
  or step onto a joinable resource-queue cell (channel 3) in view.
- ``RETURN`` (loaded): descend the search-pheromone gradient (the oldest marks lie nearest the
  nest, where the search began), colouring the path with the resource's *trail* pheromone.
- ``ORBIT`` (loaded, within ``nest_radius`` of the caches or with cache-queue agents in view):
  circle the nest clockwise hugging the caches and the cache queues, which leads along each
  pinwheel queue to its entry; join there. Loaded agents head for any cache-queue cell in view.
- ``LEAVE`` (just unloaded): orbit the nest until a trail is sensed; search after
  ``leave_patience`` steps without one.
- ``CLIMB``: follow one resource's trail uphill and join its queue. A queue in sight with no
  entry in reach (full, or long) sends the agent searching for another resource.
- ``ERASE``: the top of a trail shows no resource queue (the resource is depleted): walk
  down the trail erasing it.

Decisions where the paper, the SPEC and the reference code are vague:

- Search pheromone: the reference lays 1 (alpha = 1) and evaporates it by 0.925 per step,
  so a mark laid at step s reads 0.925**(t - s). The ground stores s: every rule only
  compares concentrations, and comparing steps is the same comparison without float
  underflow (0.925**512 ~ 5e-18). The decay is thus exact and follows ``batch.step`` (all
  batches of one step, as in a multi-host run, read the same values);
  :meth:`PheromoneGround.search_values` gives the concentrations. Cells are marked on the
  first visit only (the reference's "no pheromone here: drop"): that makes the gradient
  point home. A returning agent only descends to marks older than the oldest it has reached
  this trip, and takes one step straight home (odometry) where there is none, so a local
  minimum of the gradient cannot trap it (the reference looped there).
- Trail pheromone: one layer per resource (the reference's per-resource stack), named by the
  queue's spot-0 cell where the agent left full. Its concentration falls by one factor per
  cell walked from the resource, so the ground stores the hop count; overlapping walks keep
  the strongest (fewest hops), hence every trail cell has a stronger neighbour and climbing
  always reaches the resource. Only agents that left full colour (a partial load means the
  resource just ran out). The trail ends where the agent enters ``ORBIT`` or joins a cache.
- Trails are found at the nest (``LEAVE``), as in the reference; searching agents ignore
  them (following them from anywhere piled agents onto the first resources found).
- Pheromones are smelled on the 3x3 view by both variants. C-SAF-11 uses its 11x11 camera for
  queues: searching agents head straight for the nearest joinable resource-queue cell in
  view (the SPEC's scan), loaded agents for the nearest cache-queue cell; climbing and
  leaving agents look at the 3x3 only (scanning there too sent every agent leaving the nest
  to the one resource visible from it).
- Anti-deadlock: ties are broken at random; when the wanted cell is taken, take another
  useful move, else wait or step aside at random. Staying is a move into a wall, else a JOIN
  that has no effect. (The reference variant below does neither.)
- Start: each agent's first heading points away from the nest (diagonal ties split by agent
  id), and with nothing marked around it walks straight: the team leaves in different
  directions.
- Wipeouts: the policy cannot see the world, so the harness calls :meth:`CSAFPolicy.wipe` at
  the start of each window: all marks vanish and none is laid for ``wipeout_steps`` steps,
  as SPEC §2 does with the world's pheromone. Returning agents then head straight home and
  searching agents walk straight (the right-turn rule would spin on unmarked ground).
- Every agent reads the ground as it was at the start of the step; the marks laid during a
  step land when the next step begins, so splitting a step's agents over several batches
  changes nothing.

The reference variant (``csaf-ref``, ``csaf11-ref``)
-----------------------------------------------------
``CSAFPolicy(reference=True)`` (and ``CSAF11Policy(reference=True)``) reproduces how the
authors' code (github marmotlab/ForMIC, ``csaf_policy.py`` and ``csaf_policy_11.py``) runs
C-SAF: its teams jam at the nest, which is why the paper's C-SAF curves fall with team size.
The defaults (``csaf``, ``csaf11``) stay the baselines we report: they run in the same world
as every other algorithm (five-slot queues, SPEC §1; a fresh random agent order each step) and
resolve collisions instead of deadlocking, so their numbers measure C-SAF's rules.
The variant's numbers measure a different world (one-slot queues for C-SAF's runs only) and
a harness in which blocked agents deadlock. The differences, each from the reference code:

- One-slot queues: its controller sets every queue's length to 1 (``rc.queue.length = 1``,
  caches and resources alike). The variant's run needs ``queue_len=1`` in the world:
  ``formic_runtime.registry.POLICY_WORLD_OVERRIDES``, which ``formic sim``, ``formic eval`` and
  ``formic run`` apply to the run's scenario (so the scenario recorded shows it).
- Agents act in id order: its ``step_all_agents`` loop moves agent 1, then 2, ..., each
  seeing the moves before it; the world's ``agent_order="id"`` (same override).
- A blocked agent never yields: it keeps the action it tried as its heading, and its rules
  return a move into a taken cell ("going to be invalid (blocked) ... better to no-op"; the
  nest orbit keeps going ahead; the run to a resource repeats its move until it stands on
  the entry). Here, wherever the default takes another useful move, side-steps or waits at
  random (``_sidestep``), the variant retries the move it wanted (``_retry``): the move fails
  and the agent waits, heading kept, until the cell clears; a straight walk waits behind an
  agent instead of turning. Rules that choose among several free cells still do (as the
  reference's gradient rules take the first free one); a wall is still walked around, in a
  fixed order (retrying into a wall would never end). JOIN is still chosen only when the
  world allows it (a full one-slot queue shows no entry, in the reference too).
- Ties go N, E, S, W (its ``argmax``, ``np.where(...)[0][0]`` and ordered ``if`` chains):
  equal pheromone, the two moves towards a diagonal offset, a wall turn (the lower of right
  and left); equally near queue cells clockwise from north; where trails meet, the smallest
  key. The variant draws no random numbers at all.
- Reproduced slips: (1) searching, when right, ahead and left are all marked or taken, the
  reference's fallback takes an unmarked neighbour in N, E, S, W order looking at obstacles
  only, not at agents; the variant does so (and retries a taken one) where the default
  would turn back to a free unmarked cell only. (2) Just after unloading, the reference
  checks the cell behind the agent with the heading of its JOIN, which reads its 11x11
  view's corner (+5, +5): it waits while any agent stands there; so does the variant (when
  the world's view is at least 11x11).

Evidence, measured on an earlier version of this variant (one-slot queues, blocked agents
always wait, ties in the fixed order; without slips 1 and 2) on 128x128, 512 steps, nominal
timing: C-SAF-11 deposited 186/182/148/128 food at 16/32/64/128 agents, close to the paper's
falling curve; one-slot queues alone gave 274/408/521/190.
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
STATE_NAMES = ("new", "search", "return", "orbit", "leave", "climb", "erase")
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

    def trail(self, key: int) -> np.ndarray:
        layer = self.trails.get(key)
        if layer is None:
            layer = self.trails[key] = np.full(self.shape, NO_TRAIL, dtype=np.int32)
        return layer

    def mark(self, row: int, col: int, step: int) -> None:
        if self.marked_at[row, col] < 0:
            self.marked_at[row, col] = step

    def colour(self, key: int, row: int, col: int, hops: int) -> None:
        layer = self.trail(key)
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

    def seen(self, channel: int, dr: int, dc: int) -> float:
        return float(self.obs[channel, self.centre + dr, self.centre + dc])

    def sees(self, channel: int, radius: int = 1) -> bool:
        k = self.centre
        return bool(self.obs[channel, k - radius:k + radius + 1, k - radius:k + radius + 1].any())

    def walled(self, d: int) -> bool:
        """Whether the move ``d`` runs into a wall (outside, an obstacle, a resource or a cache)."""
        r, c = self.cell(d)
        return not self.inside(r, c) or self.seen(CH_BLOCKED, _DR[d], _DC[d]) > 0

    def nearest(self, channel: int, radius: int, rng: np.random.Generator | None) -> tuple[int, int] | None:
        """Offset of the nearest cell of ``channel`` within ``radius`` that no agent stands on;
        ties at random, or clockwise from north when ``rng`` is None (the reference variant)."""
        k = self.centre
        window = (slice(k - radius, k + radius + 1),) * 2
        free = (self.obs[channel][window] > 0) & (self.obs[CH_EMPTY_AGENTS][window] == 0)
        free &= self.obs[CH_CARRYING_AGENTS][window] == 0
        free[radius, radius] = False
        offsets = np.argwhere(free) - radius
        if len(offsets) == 0:
            return None
        dist = np.abs(offsets).sum(axis=1)
        best = np.flatnonzero(dist == dist.min())
        if rng is None:
            dr, dc = min(offsets[best].tolist(), key=_clockwise)
            return int(dr), int(dc)
        dr, dc = offsets[best[rng.integers(len(best))]]
        return int(dr), int(dc)

    def stay(self) -> int:
        """An action that leaves the agent where it is: a move into a wall, else a null JOIN."""
        for d in range(4):
            if self.walled(d):
                return d
        return JOIN


def _clockwise(offset) -> float:
    """Bearing of an offset clockwise from north: N, NE, E, SE, S, SW, W, NW (the reference
    variant's fixed tie order, which on the four neighbours is N, E, S, W)."""
    dr, dc = offset
    return float(np.arctan2(dc, -dr) % (2 * np.pi))


class CSAFPolicy(Policy):
    """C-SAF (``view=3``) or C-SAF-11 (``view=11``), see the module docstring; ``reference``
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
               "last_pos", "counter", "went_out", "floor")

    def reset(self, n_agents: int, seed: int) -> None:
        self.rng = np.random.default_rng([seed, 13])
        self.ground: PheromoneGround | None = None
        self.step = -1
        self._writes: list[tuple] = []  # marks laid this step, landing at the next one
        self._blackout_steps: int | None = None  # a wipe() waiting for its first step
        self.radius = self.view // 2  # how far queue entries are looked for
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
            self._apply_writes()
            self.step = batch.step
            if self._blackout_steps is not None:
                self.ground.blackout_until = batch.step + self._blackout_steps
                self._blackout_steps = None
        if len(batch):
            self._grow(int(np.max(batch.agent_ids)) + 1)
        self.radius = min(self.view, batch.observations.shape[-1]) // 2
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
            actions[k] = self._decide(agent)
            if actions[k] < 4:
                self.heading[i] = actions[k]
        if self.step < self.ground.blackout_until:
            self._writes.clear()  # nothing is laid during a wipeout
        return actions

    def _apply_writes(self) -> None:
        ground = self.ground
        for kind, *args in self._writes:
            if kind == "mark":
                ground.mark(*args)
            elif kind == "colour":
                ground.colour(*args)
            else:
                ground.erase(*args)
        self._writes.clear()

    # -------------------------------------------------------------- transitions
    def _start(self, a: _Agent, load: float) -> None:
        """First sight of an agent: head away from the nest (diagonal ties split by id)."""
        centre_r, centre_c = nest_centre(a.height, a.width)
        dr, dc = a.row - centre_r, a.col - centre_c
        vertical = SOUTH if dr > 0 else NORTH
        horizontal = EAST if dc > 0 else WEST
        if abs(dr) != abs(dc):
            self.heading[a.i] = vertical if abs(dr) > abs(dc) else horizontal
        else:
            self.heading[a.i] = vertical if a.i % 2 == 0 else horizontal
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
        elif self.queued_since[i] and not carrying:  # released empty: the resource is gone
            self.state[i] = SEARCH
        elif carrying and self.state[i] not in (RETURN, ORBIT):
            self._start_return(a, colour=False)
        elif not carrying and self.state[i] in (RETURN, ORBIT):
            self.state[i] = SEARCH
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
        entry = a.nearest(CH_RESOURCE_ENTRY, self.radius if state == SEARCH else 1, self._tie_rng)
        if entry is not None:
            if state == SEARCH:  # still exploring: the way to the queue joins the gradient
                self._writes.append(("mark", a.row, a.col, self.step))
            return self._toward(a, *entry)
        if state == CLIMB:
            return self._climb(a)
        if state == ERASE:
            return self._erase(a)
        if state == LEAVE:
            return self._leave(a)
        return self._search(a)

    # ------------------------------------------------------------------- search
    def _search(self, a: _Agent) -> int:
        i = a.i
        marked_at = self.ground.marked_at
        self._writes.append(("mark", a.row, a.col, self.step))
        stamps = [self._stamp(a, d) for d in range(4)]
        h = self.heading[i]
        if marked_at[a.row, a.col] < 0 and max(stamps) < 0:
            return self._straight(a, h)  # nothing sensed around: keep going
        if self.reference:
            for d in ((h + 1) % 4, h, (h + 3) % 4):  # right, ahead, left
                if a.valid[d] and stamps[d] < 0:
                    return d
            for d in range(4):  # the reference's fallback: N, E, S, W, other agents unseen
                if not a.walled(d) and stamps[d] < 0:
                    return d  # taken by an agent: the move fails, and is tried again
        else:
            for d in ((h + 1) % 4, h, (h + 3) % 4, (h + 2) % 4):  # right, ahead, left, back
                if a.valid[d] and stamps[d] < 0:
                    return d
        own = marked_at[a.row, a.col]
        newer = [d for d in range(4) if a.valid[d] and d != (h + 2) % 4 and stamps[d] > own]
        if newer:
            return self._pick(newer, [-stamps[d] for d in newer])
        return self._straight(a, h)

    def _straight(self, a: _Agent, h: int) -> int:
        if self.reference:  # an agent ahead: wait for it; a wall: turn, N, E, S, W first
            for d in (h, min((h + 1) % 4, (h + 3) % 4), max((h + 1) % 4, (h + 3) % 4), (h + 2) % 4):
                if not a.walled(d):
                    return d
            return a.stay()
        if a.valid[h]:
            return h
        turns = [d for d in ((h + 1) % 4, (h + 3) % 4) if a.valid[d]]
        if turns:
            return turns[self.rng.integers(len(turns))]
        return (h + 2) % 4 if a.valid[(h + 2) % 4] else a.stay()

    def _stamp(self, a: _Agent, d: int) -> int:
        r, c = a.cell(d)
        return int(self.ground.marked_at[r, c]) if a.inside(r, c) else -1

    def _follow_trail(self, a: _Agent) -> bool:
        """Start climbing a trail sensed in the 3x3 view (a random layer where several meet)."""
        ground = self.ground
        cells = [(a.row, a.col)] + [a.cell(d) for d in range(4)]
        cells += [(a.row + dr, a.col + dc) for dr in (-1, 1) for dc in (-1, 1)]
        for r, c in cells:
            if not a.inside(r, c) or ground.trail_count[r, c] == 0:
                continue
            keys = ground.layers_at(r, c)
            if keys:
                self.trail_key[a.i] = min(keys) if self.reference else keys[self.rng.integers(len(keys))]
                self.state[a.i] = CLIMB
                return True
        return False

    # ------------------------------------------------------------- trail rules
    def _climb(self, a: _Agent) -> int:
        i = a.i
        key = int(self.trail_key[i])
        layer = self.ground.trails.get(key)
        if layer is None:
            self.state[i] = SEARCH
            return self._search(a)
        own = int(layer[a.row, a.col])
        hops = [int(layer[a.cell(d)]) if a.inside(*a.cell(d)) else NO_TRAIL for d in range(4)]
        lower = [d for d in range(4) if hops[d] < own]
        movable = [d for d in lower if a.valid[d]]
        if movable:
            return self._pick(movable, [hops[d] for d in movable])
        if a.sees(CH_RESOURCE_QUEUED):  # at the queue, but no entry in reach: try elsewhere
            self.state[i] = SEARCH
            return self._search(a)
        if lower:  # the way up is taken by another agent
            return self._retry(a, lower, hops) if self.reference else self._sidestep(a)
        if own == NO_TRAIL:
            diagonal = [(dr, dc) for dr in (-1, 1) for dc in (-1, 1)
                        if a.inside(a.row + dr, a.col + dc) and layer[a.row + dr, a.col + dc] != NO_TRAIL]
            if diagonal and self.reference:
                return self._toward(a, *min(diagonal, key=_clockwise))
            if diagonal:
                return self._toward(a, *diagonal[self.rng.integers(len(diagonal))])
            self.state[i] = SEARCH  # lost the trail
            return self._search(a)
        self.state[i] = ERASE  # the top of the trail, and no resource there
        return self._erase(a)

    def _erase(self, a: _Agent) -> int:
        i = a.i
        key = int(self.trail_key[i])
        layer = self.ground.trails.get(key)
        own = NO_TRAIL if layer is None else int(layer[a.row, a.col])
        if own == NO_TRAIL:
            self.state[i] = SEARCH
            return self._search(a)
        self._writes.append(("erase", key, a.row, a.col))
        hops = [int(layer[a.cell(d)]) if a.inside(*a.cell(d)) else NO_TRAIL for d in range(4)]
        down = [d for d in range(4) if own < hops[d] < NO_TRAIL]
        if not down:  # the bottom of the trail
            self.state[i] = SEARCH
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
        entry = a.nearest(CH_CACHE_ENTRY, self.radius, self._tie_rng)
        if entry is not None:
            return self._toward(a, *entry)
        if self.state[i] == RETURN:
            if self._ring(a.row, a.col, a) > self.nest_radius and not a.sees(CH_CACHE_QUEUED):
                return self._descend(a)
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
        stamps = [self._stamp(a, d) for d in range(4)]
        lower = [d for d in range(4) if 0 <= stamps[d] < self.floor[i]]
        movable = [d for d in lower if a.valid[d]]
        if movable:
            return self._pick(movable, [stamps[d] for d in movable])
        if lower:
            return self._retry(a, lower, stamps) if self.reference else self._sidestep(a)
        return self._home(a)

    def _home(self, a: _Agent) -> int:
        """One step straight towards the nest (odometry)."""
        h, w = nest_cache_cells(a.height, a.width)[-1]  # the SE cache
        dr = min(max(a.row, h - 1), h) - a.row
        dc = min(max(a.col, w - 1), w) - a.col
        return self._toward(a, dr, dc)

    def _ring(self, row: int, col: int, a: _Agent) -> int:
        """Chebyshev distance from the 2x2 nest (1: the cells around the caches)."""
        h, w = nest_cache_cells(a.height, a.width)[-1]  # the SE cache
        return max(h - 1 - row, row - h, w - 1 - col, col - w, 0)

    def _orbit(self, a: _Agent) -> int:
        """Circle the nest clockwise with the caches and the cache queues on the right: the
        move towards the nest when it gets closer, else around, else away from it."""
        i = a.i
        h, w = nest_cache_cells(a.height, a.width)[-1]  # the SE cache
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
        ring = self._ring(r, c, a)
        order = [around, outward]
        ir, ic = a.cell(inward)
        if not self.went_out[i] and self._ring(ir, ic, a) < ring:
            order.insert(0, inward)
        for d in order:
            if a.valid[d]:
                self.went_out[i] = d == outward
                return d
        if self.reference:  # boxed in: wait for the first of those moves to clear
            return self._retry(a, order)
        return self._sidestep(a)  # boxed in (perhaps on a queue's spot 0): make room

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
            self.state[i] = SEARCH
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
        if self.reference:
            return self._retry(a, options)
        return self._sidestep(a)

    def _sidestep(self, a: _Agent) -> int:
        """The wanted cell is taken: wait or step aside at random (agents never lock)."""
        moves = [d for d in range(4) if a.valid[d]]
        if not moves or self.rng.random() < 0.5:
            return a.stay()
        return moves[self.rng.integers(len(moves))]

    def _pick(self, options: list[int], costs: list[int]) -> int:
        """The cheapest option, ties at random (the reference variant: N, E, S, W first)."""
        best = min(costs)
        ties = [d for d, cost in zip(options, costs) if cost == best]
        if self.reference:
            return min(ties)
        return ties[self.rng.integers(len(ties))] if len(ties) > 1 else ties[0]

    def _retry(self, a: _Agent, wanted: list[int], costs: list[int] | None = None) -> int:
        """The reference variant's answer to a blocked way: the first wanted move (in the
        given order, or the cheapest by ``costs[d]``, then N, E, S, W) that is not into a
        wall, although another agent stands there: the move fails and the agent waits, its
        heading kept, until the cell clears. Only when every wanted move is into a wall: the
        first free move in N, E, S, W order, else stay."""
        if costs is not None:
            wanted = sorted(wanted, key=lambda d: (costs[d], d))
        for d in wanted:
            if not a.walled(d):
                return d
        moves = [d for d in range(4) if a.valid[d]]
        return moves[0] if moves else a.stay()

    @property
    def _tie_rng(self) -> np.random.Generator | None:
        """The generator for random ties, None for the reference variant's fixed order."""
        return None if self.reference else self.rng


class CSAF11Policy(CSAFPolicy):
    """C-SAF-11: C-SAF with the 11x11 view (the paper's fair-comparison variant)."""

    def __init__(self, **kwargs):
        super().__init__(view=11, **kwargs)
