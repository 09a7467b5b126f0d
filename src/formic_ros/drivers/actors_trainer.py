"""The trainer node of K actors (``formic train-ros --actors K``, ``formic trainer --actors K``):
synchronous updates. Each actor (a world and its learning host, :mod:`formic_ros.launch.actors`)
plays one of the configuration's meta-agent worlds and sends its chunk's rollout of the
current weights; the node joins the K rollouts in team-wide agent order
(:func:`formic_trainer.rollout.join_rollouts`: the one rollout ``formic train`` makes of all
its worlds), makes one update and broadcasts its weights, which every actor waits for.

An actor is told apart by its agents (a world's team-wide ids are its own). One that sends
nothing within ``deadline_s`` of the first rollout of an update (killed, stalled, cut off) is
left out of it: one warning line names it, its rollout counts as lost, and the update goes on
with the others. Its rollouts of older weights, when they come, are dropped (counted); a
restarted actor takes the newest weights (latched) and its next rollout joins again. A trainer
restarted from its checkpoint under running actors gathers rollouts of the checkpoint's version:
the hosts act with its weights from their next chunk on (a learning host's restart rule).

:meth:`ActorsTrainerNode.timing` splits an update's cycle, on the trainer's clock, into the
time away (weights out until the first rollout of them is in: weights crossing, acting,
rollout crossing), the gather (first to last actor's rollout) and learning (the update and
publishing its weights): what docs/ros.md's lossy-link figures are made of.

Asynchronous (``synchronous=False``, the actors' hosts on ``switch="newest"``): every actor's
rollout is one update as it comes, when it is at most ``max_lag`` versions old (older ones are
dropped, counted), and each actor's episode end is one episode of the learning curve with its
own food. The node publishes how many rollouts it has taken from each actor (``rollouts_taken``,
JSON with an id of this trainer's run, latched; at once and after each rollout): a host runs at
most ``AHEAD_CHUNKS`` rollouts ahead of it, so when the learner is the slower side the actors
wait rather than the queue and the lag growing. The actors never wait for an update, so learning
changes: an update follows one world's rollout, and the weights that acted may be a few versions
old (docs/ros.md, "Actors")."""

from __future__ import annotations

import json
import time
import uuid

import numpy as np
from formic_interfaces.msg import Rollout as RolloutMsg
from std_msgs.msg import String

import formic_topics as topics
from formic_trainer.learner import Learner
from formic_trainer.rollout import Rollout, join_rollouts

from .. import qos
from .trainer import TrainerNode


class ActorsTrainerNode(TrainerNode):
    """Node ``trainer`` for ``actors`` actors, one per meta-agent world of the configuration."""

    def __init__(self, learner: Learner, actors: int, namespace: str = topics.DEFAULT_NAMESPACE,
                 deadline_s: float = 30.0, synchronous: bool = True, max_lag: int = 0):
        teams = learner.cfg.teams
        if actors != len(teams):
            raise ValueError(f"{actors} actors for {len(teams)} worlds (teams={list(teams)}): one actor per world")
        self.actors, self.deadline_s = actors, deadline_s
        self.world_starts = np.cumsum([0, *teams])[:-1]  # an actor's first team-wide agent id
        self.pending: dict[int, Rollout] = {}  # actor -> its rollout of the current weights
        self.gather_started = 0.0
        self.published_at: float | None = None  # when the newest update's weights went out
        self.first_update_at = 0.0
        self.phases_s = {"away": 0.0, "gather": 0.0, "learn": 0.0}  # summed over the updates after the first
        self.synchronous = synchronous
        self.actor_food = np.zeros(actors)  # asynchronous: each actor's food in its episode so far
        self.taken = np.zeros(actors, dtype=np.int64)  # asynchronous: rollouts taken from each actor
        super().__init__(learner, namespace, max_lag=0 if synchronous else max_lag)
        self.episodes_per_end = actors
        if not synchronous:  # at once, with this trainer's id: a host that sees a new id recounts from it
            self.trainer_id = uuid.uuid4().hex[:12]
            self.taken_pub = self.create_publisher(String, topics.ROLLOUTS_TAKEN, qos.LATCHED)
            self.publish_taken()

    def actor_of(self, rollout: Rollout) -> int:
        return int(np.searchsorted(self.world_starts, rollout.agent_ids[0], side="right") - 1)

    def on_rollout(self, msg: RolloutMsg) -> None:
        if (rollout := self.take(msg)) is None:
            return
        actor = self.actor_of(rollout)
        if not self.synchronous:  # one update a rollout, within max_lag; the actor hears it was taken
            updates = self.updates
            self.learn_if_fresh(rollout)
            if self.updates > updates:
                self.published_at = time.monotonic()
                self.first_update_at = self.first_update_at or self.published_at
            self.taken[actor] += 1
            self.publish_taken()
            return
        if rollout.weights_version != self.learner.version or actor in self.pending:
            self.drop(f"actor {actor}'s rollout of weights version {rollout.weights_version} (now gathering "
                      f"version {self.learner.version}'s)")
            return
        if not self.pending:
            self.gather_started = time.monotonic()
        self.pending[actor] = rollout
        if len(self.pending) == self.actors:
            self.update()

    def update(self) -> None:
        gathered = time.monotonic()
        rollout = join_rollouts(list(self.pending.values()))
        self.pending.clear()
        self.learn_from(rollout, 0)
        published = time.monotonic()
        if self.published_at is None:
            self.first_update_at = published
        else:
            for phase, seconds in (("away", self.gather_started - self.published_at),
                                   ("gather", gathered - self.gather_started), ("learn", published - gathered)):
                self.phases_s[phase] += seconds
        self.published_at = published

    def publish_taken(self) -> None:
        self.taken_pub.publish(String(data=json.dumps(
            {"trainer": self.trainer_id, "taken": {str(k): int(n) for k, n in enumerate(self.taken)}})))

    def close_episode(self, rollout: Rollout) -> str:
        if self.synchronous:
            return super().close_episode(rollout)
        actor = self.actor_of(rollout)
        self.actor_food[actor] += rollout.food
        if not rollout.done:
            return ""
        food, self.actor_food[actor] = self.actor_food[actor], 0.0
        self.learner.end_episodes(1, {"food_mean": float(food)})
        return f"; actor {actor}'s episode food {food:.1f}"

    def timing(self) -> dict:
        """Updates per second and (synchronous) the mean seconds an update spends in each phase,
        over the updates after the first (whose wait includes the actors' start-up)."""
        timed = self.updates - 1
        if timed < 1:
            return {"timed_updates": 0}
        rate = {"timed_updates": timed, "updates_per_s": timed / (self.published_at - self.first_update_at)}
        return rate | ({f"{phase}_s": seconds / timed for phase, seconds in self.phases_s.items()}
                       if self.synchronous else {})

    def report_silence(self) -> None:
        """Also the gather's deadline: actors silent for ``deadline_s`` since an update's first
        rollout are left out of it, one line naming them."""
        super().report_silence()
        if not self.pending or time.monotonic() - self.gather_started < self.deadline_s:
            return
        missing = sorted(set(range(self.actors)) - self.pending.keys())
        self.lost += len(missing)
        self.get_logger().warning(
            f"actor {', '.join(map(str, missing))} sent no rollout of weights version {self.learner.version} within "
            f"{self.deadline_s:g} s: updating from actor {', '.join(map(str, sorted(self.pending)))} "
            f"({self.lost} rollouts lost so far)")
        self.update()
