"""The world: grid, agents, queues, pheromones and score, stepped by the SPEC's rules.

One time step (SPEC §1), in this order:

1. Pheromone decay: P <- beta * P; at the first step of a wipeout P <- 0.
2. Every free agent acts once, in a fresh random permutation drawn from the world's seeded
   generator (``kernels.act_agents``). Moves into in-bounds free cells succeed at once;
   JOIN takes the nearest joinable queue of the right type (entry cell or a neighbour of it);
   a carrying agent deposits pheromone on the cell it stood on, then its intensity decays.
3. Queues advance when spot 0 is empty, and spot 0 is served (``kernels.serve_queues``):
   under the default ``timing="reference"`` a queue that moved up serves nobody this step and
   a load at a resource takes 11 steps (SPEC §1 "Timing"); ``timing="nominal"`` is exactly
   1/rate steps and serves in the step the queue moved up.
   Depleted finite resources vanish, release their queue and reappear elsewhere.
4. Rewards are final; observations and action masks are produced.

Loads are integers in units of 1/D (``WorldConfig.load_denominator``) so gathering and
drop-off take exactly 1/rate service steps (plus the reference timing's held step).
"""

from __future__ import annotations

import hashlib
from dataclasses import dataclass

import numpy as np

from . import kernels
from .config import WorldConfig
from .geometry import DIRECTION_DELTAS, FREE, N_ACTIONS, NO_ACTION, RESOURCE, nest_centre, queue_cells
from .observation import ObservationBuilder
from .pheromones import deposit_values, highway_map
from .scenario import (
    ResourceSpec,
    Scenario,
    ScenarioError,
    all_queue_cells,
    find_resource_strip,
    generate_scenario,
    passable_component_reaches,
    reserved_cells,
    static_grid,
)

_RESPAWN_TRIES = 1000
# what World.step changes (World.snapshot/restore): every array it writes, in place or anew
_STEPPED_ARRAYS = ("grid", "pheromone", "agent_at", "pos", "load", "queue_of", "spot_of", "intensity", "last_move",
                   "queue_cells", "queue_members", "queue_count", "queue_head", "resource_pos", "resource_dir",
                   "resource_capacity", "resource_remaining", "entry_owner", "resource_collect_reward", "rewards")


@dataclass
class StepResult:
    """What one step produced, for every agent (arrays indexed by agent id)."""

    observations: np.ndarray  # (N, 8, V, V) float32
    action_mask: np.ndarray  # (N, 5) bool, environment validity
    rewards: np.ndarray  # (N,) float64
    food: float  # food deposited at the nest during this step
    done: bool  # the episode has reached its length


class World:
    """The simulation core. No ROS, no policies: scenario in, actions in, state out."""

    def __init__(self, scenario: Scenario):
        self.reset(scenario)

    # ------------------------------------------------------------------ reset
    def reset(self, scenario: Scenario) -> StepResult:
        """Restore the scenario's initial state; returns the step-0 observations."""
        cfg = scenario.config
        self.scenario = scenario
        self.config = cfg
        self.load_full = cfg.load_denominator
        self.gather_ticks = cfg.gather_ticks
        self.dropoff_ticks = cfg.dropoff_ticks
        self.rng = np.random.default_rng([scenario.seed, 1])
        height, width, n, qlen = cfg.height, cfg.width, cfg.n_agents, cfg.queue_len

        self.grid = static_grid(cfg, scenario.obstacles, scenario.resources)
        positions = [[r.row, r.col] for r in scenario.resources]
        self.resource_pos = np.array(positions, dtype=np.int64).reshape(-1, 2)
        self.resource_dir = np.array([r.direction for r in scenario.resources], dtype=np.int64)
        full = self.load_full
        self.resource_capacity = np.array(
            [r.capacity * full if r.capacity > 0 else -1 for r in scenario.resources], dtype=np.int64
        )
        self.resource_remaining = self.resource_capacity.copy()

        # Queues 0-3 are the nest caches (NW, NE, SW, SE); queue 4+i belongs to resource i.
        n_queues = 4 + len(scenario.resources)
        self.queue_cells = all_queue_cells(cfg, scenario.resources).reshape(n_queues, qlen, 2)
        self.queue_is_cache = np.arange(n_queues) < 4
        self.queue_resource = np.arange(n_queues, dtype=np.int64) - 4
        self.queue_members = np.full((n_queues, qlen), -1, dtype=np.int64)
        self.queue_count = np.zeros(n_queues, dtype=np.int64)
        self.queue_head = np.zeros(n_queues, dtype=np.int64)

        self.agent_at = np.full((height, width), -1, dtype=np.int64)
        self.pos = np.zeros((n, 2), dtype=np.int64)
        self.load = np.zeros(n, dtype=np.int64)
        self.queue_of = np.full(n, -1, dtype=np.int64)
        self.spot_of = np.full(n, -1, dtype=np.int64)
        self.intensity = np.zeros(n, dtype=np.float64)
        self.last_move = np.full(n, -1, dtype=np.int64)
        for a, start in enumerate(scenario.agents):
            self.pos[a] = start.row, start.col
            self.agent_at[start.row, start.col] = a
            if start.loaded:
                self.load[a] = full
                self.intensity[a] = 1.0
            if start.cache_queue >= 0:
                self._enqueue_at_start(a, start.cache_queue)

        self.entry_owner = np.full((height, width), -1, dtype=np.int64)
        kernels.refresh_entries(self.entry_owner, self.queue_cells, self.queue_count, self.queue_head, qlen)
        self.pheromone = np.zeros((height, width), dtype=np.float64)
        self.highways = highway_map(self) if cfg.highway_intensity > 0 else np.zeros((height, width))
        self.resource_collect_reward = self.collect_reward()
        self.score_ticks = 0
        self.t = 0
        self.rewards = np.zeros(n, dtype=np.float64)
        self.observer = ObservationBuilder(self)
        self._mask = np.zeros((n, N_ACTIONS), dtype=np.bool_)
        return self._result(food=0.0)

    def _enqueue_at_start(self, agent: int, q: int) -> None:
        spot = int(self.queue_count[q])
        if spot >= self.config.queue_len or tuple(self.queue_cells[q, spot]) != tuple(self.pos[agent]):
            raise ScenarioError(
                f"agent {agent} starts in cache queue {q} but not on its next free spot {spot}"
            )
        if self.load[agent] == 0:
            raise ScenarioError(f"agent {agent} starts in a cache queue without a load")
        self.queue_members[q, spot] = agent
        self.queue_count[q] += 1
        self.queue_of[agent], self.spot_of[agent] = q, spot

    # ------------------------------------------------------------------- step
    def step(self, actions: np.ndarray) -> StepResult:
        """Advance one time step. ``actions[a]`` in 0-4 for every agent (ignored when queued);
        ``NO_ACTION`` (-1) means the agent's action did not arrive: it does nothing this step."""
        actions = np.asarray(actions)
        n = self.config.n_agents
        if actions.shape != (n,):
            raise ValueError(f"expected {n} actions, got shape {actions.shape}")
        if actions.size and (actions.min() < NO_ACTION or actions.max() > 4):
            raise ValueError("actions must be integers in 0-4 (or NO_ACTION, -1)")
        if self.done:
            raise RuntimeError("episode is over; reset the world")
        cfg = self.config
        actions = actions.astype(np.int64)
        wiping = self.wipeout_active(self.t)

        # 1. pheromone decay (and the instantaneous removal at a wipeout's start)
        self.pheromone *= cfg.beta
        if self.t in self.scenario.wipeout_starts:
            self.pheromone[:] = 0.0

        # 2. free agents act one at a time in a seeded random order
        order = np.arange(n) if cfg.agent_order == "id" else self.rng.permutation(n)
        values = deposit_values(cfg, self.rng, n)
        self.rewards = np.zeros(n, dtype=np.float64)
        r = cfg.rewards
        kernels.act_agents(
            order, actions, self.grid, self.agent_at, self.pos, self.load, self.queue_of, self.spot_of,
            self.intensity, self.last_move, self.queue_cells, self.queue_is_cache, self.queue_resource,
            self.queue_members, self.queue_count, self.queue_head, self.resource_remaining,
            self.entry_owner, self.pheromone, values, cfg.pheromone_variant != "random",
            (not wiping) and cfg.deposit_strength > 0,
            cfg.effective_alpha, self.load_full, self.rewards, r.move, r.queue_wait, r.join_right,
            r.join_wrong, r.join_nothing, r.blocked,
        )

        # 3. queues advance and serve; finite resources deplete and respawn
        depleted = np.zeros(len(self.queue_cells), dtype=np.bool_)
        unloaded = kernels.serve_queues(
            self.agent_at, self.pos, self.load, self.queue_of, self.spot_of, self.intensity,
            self.queue_cells, self.queue_is_cache, self.queue_resource, self.queue_members,
            self.queue_count, self.queue_head, self.resource_remaining, self.gather_ticks,
            self.dropoff_ticks, self.load_full, self.rewards, self.resource_collect_reward, r.deposit, depleted,
            cfg.gather_holds, cfg.dropoff_holds, cfg.serve_after_move_up,
        )
        for q in np.flatnonzero(depleted):
            self._respawn(int(q))
        kernels.refresh_entries(
            self.entry_owner, self.queue_cells, self.queue_count, self.queue_head, cfg.queue_len
        )
        self.score_ticks += int(unloaded)
        self.t += 1
        # 4. rewards are final; observations
        return self._result(food=unloaded / self.load_full)

    def _respawn(self, q: int) -> None:
        """A depleted resource disappears and a new one appears at a random valid place."""
        cfg = self.config
        res = int(self.queue_resource[q])
        old = self.resource_pos[res]
        self.grid[old[0], old[1]] = FREE
        kept = [
            ResourceSpec(r, c, d, 0)
            for i, ((r, c), d) in enumerate(zip(self.resource_pos, self.resource_dir))
            if i != res
        ]
        forbidden = (self.grid != FREE) | (self.agent_at >= 0) | reserved_cells(cfg, kept)
        anchor = tuple(self.queue_cells[0, 0])
        # the new cell must not cut any other queue off the nest either
        other_queues = np.delete(self.queue_cells, q, axis=0).reshape(-1, 2)
        for _ in range(_RESPAWN_TRIES):
            placed = find_resource_strip(self.rng, forbidden, cfg.queue_len)
            if placed is None:
                continue
            row, col, direction = placed
            cells = queue_cells((row, col), direction, cfg.queue_len)
            passable = self.grid == FREE
            passable[row, col] = False
            if not passable_component_reaches(passable, anchor, np.concatenate([cells, other_queues])):
                continue
            self.grid[row, col] = RESOURCE
            self.resource_pos[res] = row, col
            self.resource_dir[res] = direction
            capacity = int(self.rng.integers(cfg.capacity_min, cfg.capacity_max + 1)) * self.load_full
            self.resource_capacity[res] = capacity
            self.resource_remaining[res] = capacity
            self.queue_cells[q] = cells
            self.resource_collect_reward = self.collect_reward()
            self.observer.grid_changed()
            return
        raise RuntimeError("no room to respawn a resource")

    def collect_reward(self) -> np.ndarray:
        """Each resource's collection reward: flat (the paper), or falling with the resource's
        distance to the nest centre (``RewardConfig.collect_distance_decay``, the reference).
        Kept in ``resource_collect_reward``, recomputed when a resource moves (reset, respawn)."""
        r = self.config.rewards
        if r.collect_distance_decay == 0.0:
            return np.full(len(self.resource_pos), r.collect)
        centre = np.asarray(nest_centre(self.config.height, self.config.width), dtype=np.float64)
        distance = np.hypot(*(self.resource_pos - centre).T)
        return r.collect * np.exp(-r.collect_distance_decay * distance)

    # ------------------------------------------------------------ observation
    def _result(self, food: float) -> StepResult:
        """The step's result, also kept as :attr:`last_result` (a new world's step-0 one)."""
        self.last_result = StepResult(
            observations=self.observer.observe(),
            action_mask=self.action_mask(),
            rewards=self.rewards.copy(),
            food=food,
            done=self.done,
        )
        return self.last_result

    def action_mask(self) -> np.ndarray:
        """Environment validity of each action for each agent, (N, 5) bool."""
        kernels.valid_actions(
            self.grid, self.agent_at, self.pos, self.load, self.queue_of, self.entry_owner,
            self.queue_is_cache, self.queue_resource, self.resource_remaining, self.queue_count,
            self.load_full, self._mask,
        )
        return self._mask.copy()

    def training_action_mask(self, valid: np.ndarray | None = None) -> np.ndarray:
        """The training filter (SPEC §4) on top of environment validity.

        Carrying agents may not move away from the nest (negative dot product with the vector
        to the nest centre; with ``training_filter="reference"``, as the authors' code, only the
        two possible moves best aligned with it) and empty agents may not reverse their last move, unless that
        leaves no possible move.
        """
        valid = self.action_mask() if valid is None else valid
        moves = valid[:, :4]
        cr, cc = nest_centre(self.config.height, self.config.width)
        to_nest = np.stack([cr - self.pos[:, 0], cc - self.pos[:, 1]], axis=1)
        dots = to_nest @ DIRECTION_DELTAS.T  # (N, 4)
        if self.config.training_filter == "reference":
            # the two best-aligned possible moves, whatever their sign (ties: lower action first)
            ranked = np.argsort(-np.where(moves, dots, -np.inf), axis=1, kind="stable")
            best_two = np.zeros_like(moves)
            np.put_along_axis(best_two, ranked[:, :2], True, axis=1)
            away = ~best_two
        else:
            away = dots < 0
        forbidden = np.where(self.carrying[:, None], away, False)
        reverse = (self.last_move + 2) % 4
        empty_reverse = (~self.carrying) & (self.last_move >= 0)
        forbidden[np.flatnonzero(empty_reverse), reverse[empty_reverse]] = True
        filtered = moves & ~forbidden
        keep_all = ~filtered.any(axis=1)  # filtering would leave no move: allow them all
        filtered[keep_all] = moves[keep_all]
        return np.concatenate([filtered, valid[:, 4:]], axis=1)

    # ------------------------------------------------------------------ state
    @property
    def done(self) -> bool:
        return self.t >= self.config.episode_steps

    @property
    def carrying(self) -> np.ndarray:
        return self.load > 0

    @property
    def queued(self) -> np.ndarray:
        return self.queue_of >= 0

    @property
    def score(self) -> float:
        """Total food deposited at the nest."""
        return self.score_ticks / self.load_full

    @property
    def loads(self) -> np.ndarray:
        return self.load / self.load_full

    def wipeout_active(self, t: int) -> bool:
        return any(s <= t < s + self.config.wipeout_steps for s in self.scenario.wipeout_starts)

    def visible_pheromone(self) -> np.ndarray:
        """The pheromone agents see: max(P, I_h * highways), 0 during a wipeout or when hidden.
        Read-only: it may be the live map."""
        cfg = self.config
        if not cfg.pheromones_visible or (self.t > 0 and self.wipeout_active(self.t - 1)):
            return np.zeros_like(self.pheromone)
        if cfg.highway_intensity > 0:
            return np.maximum(self.pheromone, cfg.highway_intensity * self.highways)
        return self.pheromone

    def snapshot(self) -> dict:
        """Everything a step changes (the random generator's state included), so that
        :meth:`restore` can take the world back and step it again with other actions: a world
        with robots applies a step tentatively and re-applies it when a robot fails its move."""
        saved = {name: getattr(self, name).copy() for name in _STEPPED_ARRAYS}
        saved.update(rng=self.rng.bit_generator.state, score_ticks=self.score_ticks, t=self.t,
                     last_result=self.last_result)
        return saved

    def restore(self, saved: dict) -> None:
        """Back to a :meth:`snapshot` (which stays usable: it can be restored again)."""
        grid_changed = not np.array_equal(self.grid, saved["grid"])
        for name in _STEPPED_ARRAYS:
            setattr(self, name, saved[name].copy())
        self.rng.bit_generator.state = saved["rng"]
        self.score_ticks, self.t, self.last_result = saved["score_ticks"], saved["t"], saved["last_result"]
        if grid_changed:  # a resource respawned in the step taken back
            self.observer.grid_changed()

    def state_digest(self) -> str:
        """Hash of the exact dynamic state; equal digests mean identical trajectories so far."""
        h = hashlib.sha256()
        for array in (
            self.grid, self.pos, self.load, self.queue_of, self.queue_members, self.intensity,
            self.last_move, self.pheromone, self.resource_pos, self.resource_dir, self.resource_remaining,
            self.rng.bit_generator.state["state"]["state"].to_bytes(16, "little"),
        ):
            h.update(np.ascontiguousarray(array).tobytes() if isinstance(array, np.ndarray) else array)
        h.update(np.int64(self.score_ticks).tobytes())
        h.update(np.int64(self.t).tobytes())
        return h.hexdigest()[:32]


def make_world(config: WorldConfig | None = None, seed: int = 0, **overrides) -> World:
    """Convenience: generate a scenario for ``config`` (with overrides) and build its world."""
    config = (config or WorldConfig()).replace(**overrides) if overrides else (config or WorldConfig())
    return World(generate_scenario(config, seed))
