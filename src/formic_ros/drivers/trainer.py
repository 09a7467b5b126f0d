"""The trainer node: Rollouts in, updates of ``formic train``'s own learner
(:class:`formic_trainer.learner.Learner`) out as Weights versions (the updates so far; latched,
so a late host gets the newest), identified by a hash of their bytes.

A Rollout carries what the weights that acted computed (log-probabilities, values, LSTM state,
bootstrap value), so the node recomputes nothing: it drops rollouts of weights more than
``max_lag`` updates old and ends an episode (learning curve, checkpoint) when a rollout says
so. The hosts' side is :mod:`formic_ros.drivers.learning_host`. A trainer that hears no rollout for
``SILENCE_S`` says which hosts it expects one from (the graph's publishers of ``rollouts``)
and whether they have its newest weights.
"""

from __future__ import annotations

import contextlib
import hashlib
import time
from collections.abc import Callable
from pathlib import Path

from formic_interfaces.msg import Rollout as RolloutMsg
from formic_interfaces.msg import Weights
from rclpy.duration import Duration
from rclpy.node import Node

from formic_agent.checkpoint import state_dict_bytes
import formic_topics as topics
from formic_trainer.config import TrainConfig, require_distributable
from formic_trainer.learner import Learner
from formic_trainer.rollout import Rollout

from .. import qos
from ..convert_learning import WeightsPayload, decode_rollout, encode_weights
from ..env import ros_session
from ..graph import publishers_of
from ..parameters import declare_settings, settings_of
from formic_runtime.signals import stop_requests
from .lag import DEFAULT_MAX_LAG

SILENCE_S = 10.0  # no rollout for this long: the trainer names the hosts it waits for (again at 2x, 4x, ...)


class TrainerNode(Node):
    """Node ``trainer``: one update per rollout, then the new weights."""

    def __init__(self, learner: Learner, namespace: str = topics.DEFAULT_NAMESPACE, max_lag: int = DEFAULT_MAX_LAG):
        super().__init__("trainer", namespace=namespace)
        declare_settings(self, settings_of(learner.cfg) | {"max_lag": max_lag, "run_dir": str(learner.run_dir)})
        self.learner, self.max_lag = learner, max_lag
        self.received = self.updates = self.dropped = self.lost = 0  # lost: actors' rollouts never sent
        self.episodes_per_end = 1  # episodes an ending rollout ends (actors: one per world)
        self.ended = -1  # the newest episode ended
        self.episode_food = 0.0  # of the rollouts since then
        self.weights_pub = self.create_publisher(Weights, topics.WEIGHTS, qos.LATCHED)
        self.rollouts_sub = self.create_subscription(RolloutMsg, topics.ROLLOUTS, self.on_rollout,
                                                     qos.ROLLOUT_READER)
        self.heard_at, self.silence_report_s = time.monotonic(), SILENCE_S
        self.broadcast()
        self.get_logger().info(f"weights version {learner.version} published; waiting for rollouts")

    def broadcast(self) -> None:
        data = state_dict_bytes(self.learner.net)
        self.weights_pub.publish(encode_weights(WeightsPayload(
            self.learner.version, data, hashlib.sha256(data).hexdigest()[:12], self.learner.net.config.to_dict())))

    def take(self, msg: RolloutMsg) -> Rollout | None:
        """A rollout message heard (counted, the silence clock reset) and decoded; None, and
        counted as dropped, when it does not decode."""
        self.received += 1
        self.heard_at, self.silence_report_s = time.monotonic(), SILENCE_S
        try:
            return decode_rollout(msg)
        except ValueError as exc:
            self.drop(f"a malformed rollout: {exc}")
            return None

    def on_rollout(self, msg: RolloutMsg) -> None:
        if (rollout := self.take(msg)) is not None:
            self.learn_if_fresh(rollout)

    def learn_if_fresh(self, rollout: Rollout) -> None:
        """An update from ``rollout`` unless it is more than ``max_lag`` versions old (or of a
        version this trainer has not made): then it is dropped, counted."""
        lag = self.learner.version - rollout.weights_version
        if lag < 0:  # versions only grow: a previous trainer's, this one resumed from an older checkpoint
            self.drop(f"a rollout of weights version {rollout.weights_version}, newer than this trainer's "
                      f"{self.learner.version} (a trainer before a restart made it)")
            return
        if lag > self.max_lag:
            self.drop(f"a rollout of weights version {rollout.weights_version}, now {self.learner.version} "
                      f"(learning from at most {self.max_lag} versions back)")
            return
        self.learn_from(rollout, lag)

    def learn_from(self, rollout, lag: int) -> None:
        """One update from ``rollout`` (``lag`` versions old), the episode's end if it ends one,
        then the new weights: published after the fall guard has had its say, so that a rollback
        reaches the hosts under the new version (as in process, where the actor shares the net)."""
        stats = self.learner.learn(rollout)
        self.updates += 1
        self.learner.record("ros", stats | {"lag": lag, "rollout_food": rollout.food}, self.learner.version)
        line = (f"update {self.learner.version}: {rollout.steps}x{len(rollout.agent_ids)} (episode "
                f"{rollout.episode}, lag {lag}, food {rollout.food:.1f}) loss {stats['loss']:.3f}")
        line += self.close_episode(rollout)
        self.broadcast()
        self.get_logger().info(line)

    def close_episode(self, rollout: Rollout) -> str:
        """The learning curve's part of a rollout learned from: its food, and the episode's end
        when it ends one (the log line's ending)."""
        self.episode_food += rollout.food
        if not (rollout.done and rollout.episode > self.ended):  # several hosts: the first one's end counts
            return ""
        self.ended = rollout.episode
        self.learner.end_episodes(self.episodes_per_end, {"food_mean": self.episode_food / self.episodes_per_end})
        line, self.episode_food = f"; episode food {self.episode_food:.1f}", 0.0
        return line

    def drop(self, what: str) -> None:
        self.dropped += 1
        self.get_logger().warning(f"dropped {what}")

    def report_silence(self) -> None:
        """After SILENCE_S (then 2x, 4x, ...) without a rollout, one line naming the hosts a rollout
        is expected from, and whether they have acknowledged the newest weights (a host waits
        for them before it plays on): a rollout or weights lost on the way, or a host that never
        joined, shows here instead of as a silent stall."""
        quiet = time.monotonic() - self.heard_at
        if quiet < self.silence_report_s:
            return
        self.silence_report_s *= 2
        topic = self.rollouts_sub.topic_name
        hosts = publishers_of(self, topic)
        if not hosts:
            self.get_logger().warning(
                f"no rollout for {quiet:.0f} s: no host publishes on {topic} (is `formic agents --train-config` "
                "running, on this domain and namespace, and reachable: FORMIC_DDS_NETWORK, ROS_STATIC_PEERS?)")
            return
        acked = self.weights_pub.wait_for_all_acked(Duration(seconds=0))
        weights = (f"every weights reader has acknowledged version {self.learner.version}" if acked else
                   f"weights version {self.learner.version} is not acknowledged by every reader yet (lost on the way?)")
        self.get_logger().warning(f"no rollout for {quiet:.0f} s from {', '.join(hosts)} (publishing on {topic}); "
                                  f"{weights}")


def serve_trainer(cfg: TrainConfig, run_dir: Path, resume: bool = True, namespace: str = topics.DEFAULT_NAMESPACE,
                  domain_id: int | None = None, max_updates: int | None = None, max_rollouts: int | None = None,
                  max_lag: int = DEFAULT_MAX_LAG, log: Callable[[str], None] = print, actors: int = 0,
                  actor_deadline_s: float = 30.0, synchronous: bool = True) -> dict:
    """Run node ``trainer`` until SIGINT/SIGTERM, ``max_updates`` updates or ``max_rollouts``
    rollouts received (learned or dropped: what a launcher knows its hosts send). The
    checkpoint is saved on every exit but a SIGKILL (and every ``cfg.checkpoint_every``
    episodes, atomically). ``actors`` > 0: each update waits for every actor's rollout, at most
    ``actor_deadline_s`` after the first, or (not ``synchronous``) is made from each actor's
    rollout as it comes, up to ``max_lag`` versions old (:mod:`formic_ros.drivers.actors_trainer`)."""
    require_distributable(cfg)
    started = time.monotonic()
    learner = Learner(cfg, run_dir, resume=resume, log=log)
    with stop_requests() as stop, contextlib.closing(learner), ros_session(domain_id, interrupt=False) as executor:
        if actors:
            from .actors_trainer import ActorsTrainerNode

            node = ActorsTrainerNode(learner, actors, namespace, actor_deadline_s, synchronous, max_lag)
        else:
            node = TrainerNode(learner, namespace, max_lag)
        executor.add_node(node)
        while not (stop or node.updates == max_updates or node.received == max_rollouts):
            executor.spin_once(timeout_sec=0.1)
            node.report_silence()
        if not stop:  # the last weights reach the hosts before the node goes
            node.weights_pub.wait_for_all_acked(Duration(seconds=2.0))
    result = {"run_dir": str(run_dir), "version": learner.version, "updates": node.updates, "dropped": node.dropped,
              "lost": node.lost, "seconds": time.monotonic() - started}
    return (result | {"timing": node.timing()}) if actors else result  # actors: the update cycle's phases
