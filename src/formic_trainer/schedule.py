"""The schedule clock: the episode the training wheels' schedules read, held while food falls.

The action filter's annealing and the pheromone highways' fade (``filter_anneal_*``,
``curriculum_*``) are schedules over episodes. Measured on the guarded recipes (docs/training.md,
"The fourth version (paper-v4)"): a seed whose food falls while the filter fades goes on falling
if the fade goes on, and a rollback to its best weights does not hold when the filter it meets
is already weaker than the one those weights learned under. So the schedules read this clock
instead of the episode count. It advances with the episodes, except over an episode set whose
rolling food (the mean of the last ``window`` sets) is below ``hold`` x its recent peak (the
best rolling food of the last ``memory`` sets): there the wheels stay as they are until the food
comes back or the peak ages out (a lower level that lasts becomes the new reference, so a stall
is bounded). A rollback of the fall guard sets the clock back with the weights, to where it
stood when ``best.pt`` was written. Without a ``hold`` (None) the clock is the episode count, exactly.
"""

from __future__ import annotations


class ScheduleClock:
    def __init__(self, hold: float | None = None, window: int = 5, memory: int = 20, episode: int = 0):
        self.hold, self.window_size, self.memory = hold, window, memory
        self.episode = episode  # what the schedules read
        self.window: list[float] = []  # the food of the last episode sets
        self.peaks: list[float] = []  # the rolling food of the last ``memory`` full windows
        self.held = False  # whether the last episode set held the clock

    @classmethod
    def from_config(cls, cfg, episode: int = 0) -> ScheduleClock:
        return cls(cfg.anneal_hold, cfg.guard_window, cfg.anneal_memory, episode)

    def observe(self, episodes: int, food: float | None) -> bool:
        """An episode set of ``episodes`` episodes has ended with mean food ``food`` (needed
        only with a hold): the clock advances by ``episodes`` unless the set holds it. Returns
        whether it held."""
        self.held = False
        if self.hold is not None:
            if food is None:
                raise ValueError("the schedule clock's hold needs each episode set's food_mean")
            self.window = [*self.window, float(food)][-self.window_size:]
            if len(self.window) == self.window_size:
                rolling = sum(self.window) / self.window_size
                self.peaks = [*self.peaks, rolling][-self.memory:]
                self.held = rolling < self.hold * max(self.peaks)
        if not self.held:
            self.episode += episodes
        return self.held

    def roll_back(self, state: dict) -> None:
        """Back to ``state``'s clock (best.pt's); the food record starts again. Without a hold
        the clock stays the episode count (a rollback moves the weights only, as before the clock)."""
        if self.hold is not None:
            self.episode, self.window, self.peaks, self.held = state["episode"], [], [], False

    def state(self) -> dict:
        return {"episode": self.episode, "window": list(self.window), "peaks": list(self.peaks), "held": self.held}

    def load(self, state: dict) -> None:
        self.episode, self.window, self.peaks = state["episode"], list(state["window"]), list(state["peaks"])
        self.held = state["held"]
