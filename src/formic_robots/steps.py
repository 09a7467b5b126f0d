"""The robot-paced step: a world step with robot agents is applied tentatively and committed only
once every robot has physically reached the cell the step put it in (docs/robots.md, "Steps and
time").

1. The world's state is saved (:meth:`World.snapshot`) and the step applied with the core's
   ``World.step``, the one step rule every front uses.
2. Each robot gets a route: the cells from where it stands to where the core now puts it (one
   cell for a move; two for a JOIN from a neighbour of the queue's entry followed by the queue
   moving up in the same step; none when it stays, and then it is only asked to confirm).
   Robots drive in waves: one whose route enters a cell another robot has still to leave waits
   for it (a robot following another, or passing a queue entry the other leaves).
3. A robot that fails (the driver says it did not arrive in time, or was blocked) makes the
   world restore the saved state and apply the step again with that robot's action replaced by
   ``NO_ACTION``: it does nothing this step. Robots whose outcome changes drive to their new cell
   (back to their old one, if need be). NO_ACTIONs only accumulate, so this ends; a robot whose
   move no action can undo (a queue moving up) is asked again, at most ``max_attempts`` in all.

What is returned as applied (and recorded) are the actions of the committed step, NO_ACTIONs
included: replaying them with ``World.step`` alone reproduces the world exactly.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

import numpy as np

from formic_world import NO_ACTION, StepResult, World

Cell = tuple[int, int]
Route = tuple[Cell, ...]  # cells to pass through in order; the last is the goal (one cell: stay there)
# drive(attempt, routes) -> which of those robots arrived (True) or failed (False)
Drive = Callable[[int, dict[int, Route]], dict[int, bool]]


class RobotStuck(RuntimeError):
    """A robot failed to reach a cell no action can take back (its own, or a queue's move) too often."""


@dataclass
class Attempt:
    routes: dict[int, Route]
    arrived: dict[int, bool]  # robots driven in this attempt and their outcome (absent: not driven)


@dataclass
class RobotStepReport:
    result: StepResult | None  # None until the step is committed
    applied: np.ndarray  # the actions of the committed step (failed robots: NO_ACTION)
    attempts: list[Attempt] = field(default_factory=list)

    @property
    def failed(self) -> list[int]:
        """Robots that failed a move in this step (they did nothing instead)."""
        return sorted({r for a in self.attempts for r, ok in a.arrived.items() if not ok})


def _cell(world: World, agent: int) -> Cell:
    return int(world.pos[agent, 0]), int(world.pos[agent, 1])


def _adjacent(a: Cell, b: Cell) -> bool:
    return abs(a[0] - b[0]) + abs(a[1] - b[1]) == 1


def core_route(world: World, agent: int, start: Cell) -> Route:
    """The cells the core's step took ``agent`` through from ``start`` to where it is now. Every
    rule moves an agent at most one cell (a move, a JOIN into an adjacent entry, a queue moving
    up), except a JOIN followed by its queue moving up in the same step: two cells, through the
    queue spot it joined at."""
    end = _cell(world, agent)
    if end == start or _adjacent(start, end):
        return (end,)
    q, spot = int(world.queue_of[agent]), int(world.spot_of[agent])
    if q >= 0 and spot + 1 < world.queue_cells.shape[1]:
        joined = tuple(int(v) for v in world.queue_cells[q, spot + 1])
        if _adjacent(start, joined) and _adjacent(joined, end):
            return (joined, end)
    raise ValueError(f"agent {agent} went from {start} to {end} in one step: no rule moves an agent so")


def erase_loops(cells: Sequence[Cell]) -> Route:
    """``cells`` without detours that come back to a cell already passed."""
    route: list[Cell] = []
    for cell in cells:
        if cell in route:
            del route[route.index(cell) + 1:]
        else:
            route.append(cell)
    return tuple(route)


def next_wave(routes: dict[int, Route], at: dict[int, Cell], waiting: set[int]) -> list[int]:
    """The waiting robots that may drive now: none of the cells they enter is one that another
    waiting robot stands in and will leave, or passes through (a robot that stays leaves nothing)."""
    vacating = {r: {at[r], *routes[r][:-1]} for r in waiting if routes[r][-1] != at[r]}
    ready = []
    for r in sorted(waiting):
        entered = set(routes[r]) - {at[r]}
        if not any(entered & cells for other, cells in vacating.items() if other != r):
            ready.append(r)
    return ready


def robot_paced_step(world: World, actions: np.ndarray, robots: Sequence[int], drive: Drive,
                     max_attempts: int = 6) -> RobotStepReport:
    """Apply one step of ``world`` with ``actions``, committed when the ``robots`` (agent ids)
    have reached their cells: ``drive(attempt, routes)`` moves the given robots along their
    routes at once and says which arrived. Raises :class:`RobotStuck` after ``max_attempts``
    attempts in which some robot failed a move that no NO_ACTION undoes."""
    saved = world.snapshot()
    start = {r: _cell(world, r) for r in robots}
    trail = {r: (start[r],) for r in robots}  # the cells from the start to where each robot stands
    queued = {r: bool(world.queue_of[r] >= 0) for r in robots}  # its action is ignored; a queue may move it
    applied = np.asarray(actions, dtype=np.int64).copy()
    report = RobotStepReport(result=None, applied=applied)
    stubborn = 0  # attempts in which a failure could not be undone
    while True:
        result = world.step(applied)
        at = {r: trail[r][-1] for r in robots}
        # back along the trail to the start, then the core's way: without detours, less where it stands
        routes = {r: erase_loops((*trail[r][::-1], *core_route(world, r, start[r])))[1:] or (at[r],) for r in robots}
        attempt = Attempt(routes=routes, arrived={})
        report.attempts.append(attempt)
        waiting = set(robots)
        while waiting:
            wave = next_wave(routes, at, waiting)
            if not wave:  # robots waiting on each other (cannot happen for the core's moves): none moves
                break
            outcome = drive(len(report.attempts) - 1, {r: routes[r] for r in wave})
            for r in wave:
                attempt.arrived[r] = bool(outcome.get(r, False))
                waiting.discard(r)
                if attempt.arrived[r]:
                    trail[r] = erase_loops((*trail[r], *routes[r]))
                    at[r] = routes[r][-1]
            if not all(attempt.arrived[r] for r in wave):
                break  # re-plan before anyone else moves
        failed = [r for r, ok in attempt.arrived.items() if not ok]
        if not failed and not waiting:
            report.result = result
            return report
        undoable = [r for r in failed if applied[r] != NO_ACTION and not queued[r]]
        if len(undoable) < len(failed) or not failed:
            stubborn += 1
            if stubborn >= max_attempts:
                raise RobotStuck(f"step {world.t - 1}: robots {sorted(set(failed) - set(undoable)) or sorted(waiting)} "
                                 f"did not reach their cells in {max_attempts} attempts")
        applied[undoable] = NO_ACTION
        world.restore(saved)
