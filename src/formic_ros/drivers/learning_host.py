"""Distributed training's agent host: learning agents over ROS.

:class:`LearningHost` is the batched-transport node around a
:class:`formic_ros.drivers.host_actor.HostActor` (``formic train``'s actor over this host's
agents, on the weights the trainer node broadcasts); its rollouts go to the trainer as Rollout
messages. :func:`serve_learning_agents` runs one.
"""

from __future__ import annotations

import json
import os
import time
from contextlib import suppress

import numpy as np
import torch
from rclpy.duration import Duration
from rclpy.node import Node
from formic_interfaces.msg import ActionBatch, ObservationBatch, ScenarioDescription, Weights
from formic_interfaces.msg import Rollout as RolloutMsg
from std_msgs.msg import String

from formic_agent.policy import AgentBatch
import formic_topics as topics
from formic_trainer.config import TrainConfig
from formic_trainer.worlds import Frame
from formic_world import Scenario
from formic_world.geometry import N_ACTIONS

from .. import convert, qos
from ..convert_learning import encode_rollout
from ..graph import publishers_of
from ..parameters import declare_settings
from ..wire import read
from .claim import Claim
from .host_actor import HostActor
from .lag import AHEAD_CHUNKS
from .protocol import DriverProtocol, Turn
from .world_watch import WorldWatch, read_scenario


SWITCH_MODES = ("chunk", "episode", "newest")
WEIGHTS_WAIT_LOG_S = 10.0  # while a host waits for weights, it says so this often


class LearningHost(Node):
    """A batched-transport host whose agents learn (distributed training).

    The agents act as the in-process trainer's do (:class:`HostActor`: its actor, LSTM
    states and sampler under the training filter, which needs the world's ``train_masks``:
    run the world with ``--training-masks``); each chunk of ``rollout_steps`` steps of the
    learning agents goes to the trainer as a Rollout. Weights come from the trainer's latched
    ``weights`` topic. ``switch="chunk"``: after each rollout the host waits for the weights
    that rollout produced and acts on with them, exactly as the in-process trainer updates
    after each chunk (on-policy; same seeds and settings give the same learning curve).
    ``switch="episode"``: an episode is played with one weights version while the trainer
    learns from its first chunks; at the next episode's start the host waits for the updates
    of all its rollouts and takes the newest weights (each rollout carries what the weights that
    acted computed, so the trainer's PPO ratio is taken against them; with one host the lag
    stays below the chunks per episode). ``switch="newest"`` (asynchronous actors): at each
    chunk's start the host acts on with the newest weights it has, without waiting for the
    update of the rollout it just sent; but it waits while ``AHEAD_CHUNKS`` of its rollouts are
    not yet taken by the trainer (``rollouts_taken``): the bound on its lag when the learner is
    the slower side (the trainer drops rollouts more than ``max_lag`` versions old).

    An actor's host (``formic train-ros --actors K``, ``formic actor``) serves world
    ``world_index`` of the configuration's meta-agent worlds (its agents team-wide from that
    world's first) in a namespace of its own, and takes weights from and sends rollouts to ``trainer_namespace``.

    An episode starts at step 0 of a scenario the host has not played yet: observations of a
    new episode that arrive before its (latched) scenario are held until it does.

    A trainer's weights versions only grow, so weights whose version is not above the newest
    come from a restarted trainer (from its checkpoint), which waits for rollouts of exactly
    them: the host acts with them from its next chunk on, whatever version it waits for (its
    rollouts of the old trainer's weights are lost or dropped).
    """

    def __init__(self, agent_ids: list[int], cfg: TrainConfig, switch: str = "chunk", first_episode: int = 0,
                 namespace: str = topics.DEFAULT_NAMESPACE, name: str | None = None, threads: int = 1,
                 world_index: int = 0, trainer_namespace: str | None = None):
        if switch not in SWITCH_MODES:
            raise ValueError(f"unknown weights switch {switch!r}; choose from {', '.join(SWITCH_MODES)}")
        torch.set_num_threads(threads)
        self.switch, self.world_index = switch, world_index
        super().__init__(name or f"agent_host_{os.getpid()}", namespace=namespace)
        declare_settings(self, {"agent_ids": [int(a) for a in agent_ids], "switch": switch,
                                        "first_episode": first_episode, "threads": threads,
                                        "train_config": cfg, "world_index": world_index})
        self.log = self.get_logger()
        offset = sum(cfg.teams[:world_index])  # the world's agents' first team-wide id
        self.actor = HostActor(cfg, [a + offset for a in agent_ids], first_episode=first_episode)
        self.ids = self.actor.ids - offset  # the world's own ids
        self.create_subscription(ScenarioDescription, topics.SCENARIO, self._on_scenario, qos.LATCHED)
        self.create_subscription(ObservationBatch, topics.OBSERVATIONS, self._on_batch, qos.STREAM)
        weights = topics.full_name(trainer_namespace or namespace, topics.WEIGHTS)  # an actor's host: its trainer's
        self.weights_sub = self.create_subscription(Weights, weights, self._on_weights, qos.LATCHED)
        self.actions_pub = self.create_publisher(ActionBatch, f"~/{topics.ACTIONS}", qos.STREAM_WRITER)
        self.claim = Claim(self, list(self.ids), self.actions_pub.topic_name, publishers=[self.actions_pub])
        self.taken, self.sent_base = 0, 0  # switch "newest": rollouts the trainer took; sent to one before a restart
        self.taken_from = ""  # the id of the trainer that counts them
        self.ahead_wait = False  # switch "newest": waiting for the trainer to take this host's rollouts
        if switch == "newest":
            self.create_subscription(String, topics.full_name(trainer_namespace or namespace, topics.ROLLOUTS_TAKEN),
                                     self._on_taken, qos.LATCHED)
        self.rollouts_pub = self.create_publisher(RolloutMsg, topics.full_name(trainer_namespace or namespace,
                                                                              topics.ROLLOUTS), qos.ROLLOUT)
        self.protocol = DriverProtocol(whole_episodes=True)
        self.scenario: Scenario | None = None  # the newest scenario
        self.horizon = -1  # its episode's steps (-1: none yet)
        self.episodes = 0  # episodes finished
        self.episode_rollouts = 0  # rollouts sent with the weights loaded (switch "episode": in this episode)
        self.rollouts_sent = 0
        self.held: ObservationBatch | None = None  # newest observations not dealt with yet
        self.ready: tuple[AgentBatch, Frame] | None = None  # to act on once the weights allow
        self.newest = None  # the newest Weights message received
        self.restarted = False  # the newest weights are a restarted trainer's, not loaded yet
        self.wait_version: int | None = -1  # act only with weights newer than this (None: act now)
        self.answer = np.zeros(0, dtype=np.int64)
        self._start_waiting()  # for the first weights

    # ------------------------------------------------------------------------ inputs
    def _on_scenario(self, msg: ScenarioDescription) -> None:
        if msg.scenario_json in (self.protocol.newest, self.protocol.played) or (
                scenario := read_scenario(msg, self.log)) is None:
            return
        self.protocol.scenario(msg.scenario_json)
        self.scenario, self.horizon = scenario, scenario.config.episode_steps
        if (self.ids >= scenario.config.n_agents).any():
            self.log.error(f"agents {self.ids.tolist()} are not all in this team of {scenario.config.n_agents}")
        self.pump()

    def _on_weights(self, msg) -> None:
        if self.newest is not None and msg.version <= self.newest.version:
            self.log.warning(f"weights version {msg.version} after version {self.newest.version}: the trainer "
                             "restarted; acting with them from the next chunk")
            self.restarted = True
        self.newest = msg
        self.pump()

    def _on_taken(self, msg: String) -> None:
        try:
            data = json.loads(msg.data)
            trainer, taken = str(data["trainer"]), int(data["taken"].get(str(self.world_index), 0))
        except (ValueError, AttributeError, TypeError, KeyError):
            self.log.error(f"a malformed rollouts_taken message: {msg.data[:80]!r}", once=True)
            return
        if trainer != self.taken_from:  # a (re)started trainer counts from 0: what went to another is lost
            self.taken_from, self.sent_base = trainer, self.rollouts_sent - taken
        self.taken = taken
        self.pump()

    def _on_batch(self, msg: ObservationBatch) -> None:
        if not self.claim.ready():
            return  # the world re-sends step 0 until every agent is heard
        self.held = msg
        self.pump()

    # ---------------------------------------------------------------------- stepping
    def _take(self, msg: ObservationBatch) -> bool:
        """Deal with a received observation batch; False to keep holding it (a new episode's
        step 0 before its scenario)."""
        rows = convert.rows_of(msg, self.ids)  # this host's agents, in id order
        if not (rows >= 0).all():
            return True  # a re-send for other hosts' agents
        if not len(msg.train_masks):
            self.log.error("the observations carry no training masks: run the world with --training-masks",
                           once=True)
            return True
        turn = self.protocol.receive(int(msg.step), bool(msg.done))
        if turn is Turn.HOLD:
            return False
        if turn is Turn.RESEND:
            self.actions_pub.publish(convert.encode_actions(msg.step, self.ids, self.answer))
        if turn in (Turn.IGNORE, Turn.RESEND):
            return True
        batch = convert.decode_observation_batch(msg, rows)
        if turn is Turn.START:  # before its first frame: the agents' action feedback starts afresh
            if self.protocol.cut_short:
                self.log.warning("a new episode started before this one ended: its last chunk is dropped")
            self.episode_rollouts = 0
            self.actor.begin(batch, self.scenario.config.load_denominator)
        train_mask = read(msg.train_masks, np.uint8).reshape(-1, N_ACTIONS)[rows].astype(bool)
        frame = self.actor.frame(batch, train_mask, read(msg.rewards, np.float32), rows)
        if turn is not Turn.START:
            self._learn_from(frame, batch.loads, turn is Turn.END)
        if turn is Turn.END:
            self.episodes += 1
        else:
            self.ready = (batch, frame)
        return True

    def _learn_from(self, frame: Frame, loads: np.ndarray, done: bool) -> None:
        """A step's outcome: a rollout to the trainer when its chunk is complete, and which
        weights to wait for before acting on."""
        rollout = self.actor.outcome(frame, loads, done)
        if rollout is None:
            return
        self.rollouts_pub.publish(encode_rollout(rollout))
        self.episode_rollouts += 1
        self.rollouts_sent += 1
        if self.switch == "newest":  # on with the newest weights there are, unless too far ahead of the trainer
            self.ahead_wait = True
            self._start_waiting()
        elif self.switch == "chunk" or self.restarted:  # act on with the weights this rollout makes (or a restart's)
            self.wait_version = self.actor.weights_version
            self._start_waiting()
        elif done:  # start the next episode with the weights all of this one's make
            self.wait_version = self.actor.weights_version + self.episode_rollouts - 1
            self._start_waiting()

    def _start_waiting(self) -> None:
        """A wait for weights starts: reported after WEIGHTS_WAIT_LOG_S, and then as often."""
        self.waiting_since = time.monotonic()
        self.next_wait_report = self.waiting_since + WEIGHTS_WAIT_LOG_S

    def _in_flight(self) -> int:
        """Rollouts this host sent that the (asynchronous) trainer has not taken yet."""
        return self.rollouts_sent - self.sent_base - self.taken

    def _weights_ready(self) -> bool:
        if self.wait_version is None and self.ahead_wait:  # a chunk's start, switch "newest"
            if self._in_flight() >= AHEAD_CHUNKS:
                return self._still_waiting(lambda: f"waited {time.monotonic() - self.waiting_since:.0f} s for the "
                                           f"trainer to take this host's rollouts ({self._in_flight()} of "
                                           f"{self.rollouts_sent} not taken)")
            if self.newest.version != self.actor.weights_version:
                self.actor.load_weights(self.newest)
            self.ahead_wait = self.restarted = False
        if self.wait_version is None:
            return True
        # and a trainer's reader matched: a rollout published before that is never delivered (volatile), which
        # across a slow link, with an actor's world on loopback, happened to a first rollout (tests/test_lossy_link.py)
        if (self.newest is None or (self.newest.version <= self.wait_version and not self.restarted)
                or not self.rollouts_pub.get_subscription_count()):
            return self._still_waiting(self.weights_wait_report)
        self.actor.load_weights(self.newest)
        self.wait_version, self.restarted, self.episode_rollouts = None, False, 0
        return True

    def _still_waiting(self, report) -> bool:
        """False (not ready), saying ``report()`` every WEIGHTS_WAIT_LOG_S while the wait lasts."""
        if time.monotonic() > self.next_wait_report:
            self.log.warning(report())
            self.next_wait_report = time.monotonic() + WEIGHTS_WAIT_LOG_S
        return False

    def weights_wait_report(self) -> str:
        """Who this host waits for and what it knows: the graph's publishers of ``weights`` (the
        trainer) and whether they acknowledged this host's last rollout (lost on the way, or
        received and the update or its weights are late)."""
        waited = (f"waited {time.monotonic() - self.waiting_since:.0f} s for weights newer than version "
                  f"{self.wait_version}")
        trainers = publishers_of(self, self.weights_sub.topic_name)
        if not trainers:
            return (f"{waited}: no trainer publishes on {self.weights_sub.topic_name} (is `formic trainer` running, on "
                    "this domain and namespace, and reachable: FORMIC_DDS_NETWORK, ROS_STATIC_PEERS?)")
        waited += f" from {', '.join(trainers)}"
        if not self.rollouts_sent:
            return f"{waited}: none has arrived (the link?)"
        if not self.rollouts_pub.get_subscription_count():
            return f"{waited}: no trainer reader has matched this host's rollouts yet"
        if not self.rollouts_pub.wait_for_all_acked(Duration(seconds=0)):
            return f"{waited}: it has not acknowledged this host's last rollout (still crossing, or lost: the link?)"
        return f"{waited}: it acknowledged this host's last rollout; its update or the new weights are late"

    def pump(self) -> None:
        """Deal with what has arrived: the held observations, then acting when the weights allow."""
        if self.held is not None and self._take(self.held):
            self.held = None
        if self.ready is None or not self._weights_ready():
            return
        batch, frame = self.ready
        self.ready = None
        self.answer = self.actor.act_on(batch, frame)
        self.protocol.answered(batch.step)
        self.actions_pub.publish(convert.encode_actions(batch.step, self.ids, self.answer))


def serve_learning_agents(agent_ids: list[int], cfg: TrainConfig, switch: str = "chunk",
                          first_episode: int = 0, namespace: str = topics.DEFAULT_NAMESPACE,
                          name: str | None = None, episodes: int | None = None, domain_id: int | None = None,
                          threads: int = 1, world_index: int = 0, trainer_namespace: str | None = None) -> int:
    """Host learning agents until interrupted (or until ``episodes`` episodes are played and
    their rollouts delivered, or the world is gone); returns the episodes played."""
    from ..env import ros_session

    with ros_session(domain_id) as executor:
        host = LearningHost(agent_ids, cfg, switch=switch, first_episode=first_episode, namespace=namespace,
                            name=name, threads=threads, world_index=world_index,
                            trainer_namespace=trainer_namespace)
        executor.add_node(host)
        watch = WorldWatch(host)
        with suppress(KeyboardInterrupt):
            while not (episodes is not None and host.episodes >= episodes):
                executor.spin_once(timeout_sec=0.2)
                host.pump()  # also says so when the weights are late
                protocol = host.protocol
                next_step = protocol.answered_step + 1 if protocol.playing else host.horizon
                if episodes is not None and watch.ended(next_step, host.horizon):
                    break  # between episodes, or only the final observation was lost
            host.rollouts_pub.wait_for_all_acked(Duration(seconds=5.0))
        return host.episodes
