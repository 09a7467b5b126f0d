"""The fall guard: a run that drifts away from what it had learned goes back to its best weights.

Measured on the `paper` recipe (docs/training.md, "The guarded recipe"): a run can drift away
from foraging within a few dozen episode sets and not come back. The guard watches the rolling
mean of the training food over the last ``guard_window`` episode sets (from episode
``guard_after`` on); at every new best it asks for ``best.pt``, and when the rolling mean falls
below ``guard_drop`` x the best it asks for a rollback to ``best.pt`` at a lower learning rate,
at most ``guard_max`` times. From episode ``guard_restart`` on (if set) its record starts again:
the best and the window of the sets before are forgotten, so ``best.pt`` becomes the best of the
sets played from there on (a stage whose action filter ends there hands on weights that forage
without it, while the sets before were still guarded); rollbacks so far and the learning rate's
factor stay. It decides only; the learner writes, loads and logs, and keeps the
guard's :meth:`FallGuard.state` in its checkpoints so that a resumed run decides as an
uninterrupted one.
"""

from __future__ import annotations

from dataclasses import dataclass

WATCH, BEST, ROLL_BACK, SPENT = "watch", "best", "roll back", "spent"


@dataclass(frozen=True)
class Verdict:
    """What the guard asks for after an episode set: WATCH (nothing), BEST (write best.pt),
    ROLL_BACK (load best.pt, fresh optimiser, lr times ``lr_factor``) or SPENT (a fall after the
    last rollback: only ``line`` is logged); ``line`` says why, for ROLL_BACK and SPENT."""

    action: str
    line: str = ""


class FallGuard:
    def __init__(self, drop: float, window: int, after: int, most: int, lr_factor: float,
                 restart: int | None = None):
        self.drop, self.window_size, self.after, self.most, self.factor = drop, window, after, most, lr_factor
        self.restart = restart  # None = never
        self.restarted = False
        self.window: list[float] = []  # the food of the last episode sets watched
        self.best: float | None = None  # the best full-window rolling mean ...
        self.best_episode = 0  # ... and the episode it was reached at
        self.events = 0  # rollbacks so far
        self.lr_factor = 1.0  # the learning rate's factor now: lr_factor ** events

    @classmethod
    def from_config(cls, cfg) -> FallGuard | None:
        """The guard a TrainConfig asks for (None without a ``guard_drop``)."""
        if cfg.guard_drop is None:
            return None
        return cls(cfg.guard_drop, cfg.guard_window, cfg.guard_after, cfg.guard_max, cfg.guard_lr_factor,
                   cfg.guard_restart)

    def observe(self, episode: int, food: float, schedule: int | None = None) -> Verdict:
        """An episode set has ended with ``episode`` episodes played and mean food ``food``
        over its worlds. Sets ending at or before ``after`` are not watched (those played from
        episode ``after`` on are). ``after`` and ``restart`` are read on ``schedule``, the
        schedule clock's episode the set was played at plus its episodes (default: ``episode``;
        the two differ only when the clock holds, :mod:`formic_trainer.schedule`)."""
        at = episode if schedule is None else schedule
        if at <= self.after:
            return Verdict(WATCH)
        if self.restart is not None and at > self.restart and not self.restarted:  # the first set from there
            self.window, self.best, self.restarted = [], None, True
        self.window = [*self.window, float(food)][-self.window_size:]
        if len(self.window) < self.window_size:
            return Verdict(WATCH)
        rolling = sum(self.window) / len(self.window)
        if self.best is None or rolling > self.best:
            self.best, self.best_episode = rolling, episode
            return Verdict(BEST)
        if rolling >= self.drop * self.best:
            return Verdict(WATCH)
        self.window = []
        fall = f"guard: rolling food {rolling:.1f} < {self.drop:g} x best {self.best:.1f} (episode {episode}): "
        if self.events >= self.most:
            return Verdict(SPENT, fall + f"no rollback left ({self.events}/{self.most} events)")
        self.events += 1
        self.lr_factor *= self.factor
        return Verdict(ROLL_BACK, fall + f"back to episode {self.best_episode}'s weights, lr x{self.lr_factor:g}, "
                                         f"event {self.events}/{self.most}")

    def state(self) -> dict:
        """Everything :meth:`observe` depends on, for a checkpoint's progress."""
        return {"window": list(self.window), "best": self.best, "best_episode": self.best_episode,
                "events": self.events, "lr_factor": self.lr_factor, "restarted": self.restarted}

    def load(self, state: dict) -> None:
        self.window, self.best, self.best_episode = list(state["window"]), state["best"], state["best_episode"]
        self.events, self.lr_factor = state["events"], state["lr_factor"]
        self.restarted = state.get("restarted", False)  # states written before guard_restart existed
