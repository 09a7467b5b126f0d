"""The driver protocol: what a driver does with each observation of the lockstep world.

The world sends each step's observations until every agent is heard (step 0 until everyone
joined, any step after a lost answer), starts an episode at step 0 of a latched scenario, and
ends it with a ``done`` observation. :class:`DriverProtocol` turns each observation's (step,
done) into one :class:`Turn`; both agent hosts act on it, so they agree on new episodes,
re-sends and stale steps. No ROS here: the hosts feed it their messages' fields.
"""

from __future__ import annotations

from enum import Enum


class Turn(Enum):
    """What a driver does with one observation."""

    IGNORE = "ignore"  # stale, a re-send still being answered, or an episode this driver does not play
    HOLD = "hold"  # step 0 of an episode whose scenario has not arrived: keep it until it does
    RESEND = "resend"  # the step answered last, again: publish the same answer
    START = "start"  # step 0 of a new episode (the driver resets first), to answer
    STEP = "step"  # the next step, to answer
    END = "end"  # the episode's final observation (nothing to answer)


class DriverProtocol:
    """One driver's episode and step state.

    ``whole_episodes`` is the one rule the two hosts do not share. A learning host
    (``True``) plays only whole episodes of scenarios it has not played, every step in order:
    its rollouts, LSTM states and random streams begin at step 0 and a chunk holds every step,
    and training plays a new scenario each episode. So an episode starts at step 0 of a new
    scenario (held until the scenario arrives), a step other than the next is stale, and a new
    scenario's step 0 ends an episode whose final observation was lost. A plain host
    (``False``) may join at any step (a restarted host answers from where the world is: its
    policies reset from the scenario), so its episode starts when a scenario arrives, and again
    at step 0 when the world plays the same scenario once more; it answers any step newer
    than the last answered.
    """

    def __init__(self, whole_episodes: bool):
        self.whole_episodes = whole_episodes
        self.newest = ""  # the newest scenario (its JSON)
        self.played = ""  # the scenario of the episode being (or last) played
        self.playing = False
        self.ended = False  # the episode played last has ended (its final observation arrived)
        self.taken = -1  # the newest step accepted in this episode (answered, or waiting to be)
        self.answered_step = -1  # the newest step answered in this episode
        self.cut_short = False  # the episode before this one was left before its end

    def scenario(self, text: str) -> bool:
        """A scenario arrived; returns whether an episode starts now (a plain host's new one)."""
        if text in (self.newest, self.played if self.whole_episodes else ""):
            return False
        self.newest = text
        if self.whole_episodes:
            return False
        self._start()
        return True

    def receive(self, step: int, done: bool) -> Turn:
        """The turn for an observation of ``step`` (``done``: it ends the episode)."""
        if self.whole_episodes:
            return self._receive_whole(step, done)
        if not self.newest:
            return Turn.IGNORE  # no scenario yet: the world re-sends
        if done:
            self.playing, self.ended = False, True
            return Turn.END
        if not self.playing:
            if step != 0:
                return Turn.IGNORE
            self._start()  # the world plays the scenario again
            return self._take(step, Turn.START)
        if step == self.answered_step:
            return Turn.RESEND
        return self._take(step, Turn.STEP) if step > self.answered_step else Turn.IGNORE

    def _receive_whole(self, step: int, done: bool) -> Turn:
        cut_short = False
        if self.playing:
            if step == self.taken and self.taken > self.answered_step and not done:
                return Turn.IGNORE  # a re-send of the step waiting to be answered
            cut_short = step == 0 and not done and self.newest != self.played
            if cut_short:
                self.playing = False  # a new episode started before this one ended
            elif step == self.answered_step and not done:
                return Turn.RESEND
            elif step != self.answered_step + 1:
                return Turn.IGNORE
            elif done:
                self.taken, self.playing, self.ended = step, False, True
                return Turn.END
            else:
                return self._take(step, Turn.STEP)
        if done or step != 0:
            return Turn.IGNORE  # the end or the middle of an episode this driver did not play
        if self.newest == self.played:
            return Turn.HOLD
        self.played = self.newest
        self._start(cut_short)
        return self._take(step, Turn.START)

    def answered(self, step: int) -> None:
        """The answer to ``step`` went out."""
        self.answered_step = step

    def _start(self, cut_short: bool = False) -> None:
        self.playing, self.ended, self.taken, self.answered_step = True, False, -1, -1
        self.cut_short = cut_short

    def _take(self, step: int, turn: Turn) -> Turn:
        self.taken = step
        return turn
