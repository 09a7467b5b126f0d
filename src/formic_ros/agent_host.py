"""Agent host: one process that drives any set of agents over ROS.

Per-agent transport (default): every agent is its own rclpy node ``agent_K`` in the namespace,
with ``agent_K/observation`` in and ``agent_K/action`` out, all nodes in one events executor
(ROS composition). That is what ``ros2 node list`` shows and what a robot's own node replaces.
Batched transport: one node holds the ``observations``/``actions`` pair and answers for its
agents in one message. Either way the host acts once per step for all its agents (a learned
policy runs one batch), only when it has every one of its agents' observations for that step.

Policies reset from the latched scenario (seed, team size); a restarted host therefore starts
with fresh memory and answers from whatever step the world is at. Observations of a step the
host has already answered (the world re-sends step 0 until everyone is heard) get the same
actions again, never a second policy call.

Learning mode (:class:`LearningHost`, batched): the agents act for the trainer node, send
rollouts and take its weights (distributed training).
"""

from __future__ import annotations

import os
import time
from typing import TYPE_CHECKING

import numpy as np
import rclpy
from formic_interfaces.msg import (
    ActionBatch,
    AgentAction,
    AgentObservation,
    ObservationBatch,
    ScenarioDescription,
)
from rclpy.node import Node
from rclpy.parameter import Parameter
from rclpy.type_description_service import START_TYPE_DESCRIPTION_SERVICE_PARAM

from formic_agent.policy import AgentBatch, CentralPolicy
from formic_runtime.registry import world_overrides
from formic_runtime.team import Team, format_ids
from formic_runtime.threads import configure_threads
from formic_world import Scenario

from . import convert, qos

if TYPE_CHECKING:
    from formic_trainer.train import TrainConfig

TRANSPORTS = ("per-agent", "batched")


def read_scenario(msg: ScenarioDescription, log) -> Scenario | None:
    """The scenario a description carries, or None (logged) when it cannot be read."""
    try:
        return convert.scenario_from_description(msg)
    except ValueError as exc:
        log.error(f"ignoring scenario: {exc}")
        return None


def lean_node(name: str, namespace: str) -> Node:
    """An agent node without parameter, type-description or rosout endpoints: with a hundred
    agents per process those would be most of the DDS endpoints to discover, and agent nodes
    neither take parameters nor log (their host's node does)."""
    return Node(
        name, namespace=namespace, enable_rosout=False, start_parameter_services=False,
        parameter_overrides=[Parameter(START_TYPE_DESCRIPTION_SERVICE_PARAM, value=False)],
    )


class AgentHost:
    """The nodes and policies of one host; add :attr:`nodes` to an executor and spin."""

    def __init__(
        self,
        agent_ids: list[int],
        spec: str,
        model: str | None = None,
        greedy: bool = False,
        transport: str = "per-agent",
        namespace: str = qos.DEFAULT_NAMESPACE,
        name: str | None = None,
        torch_threads: int = 1,
    ):
        if transport not in TRANSPORTS:
            raise ValueError(f"unknown transport {transport!r}; choose from {', '.join(TRANSPORTS)}")
        self.ids = np.array(sorted(agent_ids), dtype=np.int64)
        self.team = Team.for_agents(spec, self.ids.tolist())
        self.world_needs = world_overrides(self.team.names)  # csaf-ref: one-slot queues
        configure_threads(torch_threads)
        for policy, _ in self.team.build(model=model, greedy=greedy).members:
            if isinstance(policy, CentralPolicy):
                raise ValueError(f"{policy.name} needs the full world: it runs as its own node")
        self.transport = transport
        self.control = rclpy.create_node(name or f"agent_host_{os.getpid()}", namespace=namespace)
        self.log = self.control.get_logger()
        self.nodes = [self.control]
        self.control.create_subscription(ScenarioDescription, qos.SCENARIO, self._on_scenario, qos.LATCHED)
        if transport == "batched":
            self.control.create_subscription(ObservationBatch, qos.OBSERVATIONS, self._on_batch, qos.STREAM)
            self.actions_pub = self.control.create_publisher(ActionBatch, qos.ACTIONS, qos.STREAM)
        else:
            self.action_pubs = {}
            for a in self.ids.tolist():
                node = lean_node(qos.agent_node_name(a), namespace)
                node.create_subscription(AgentObservation, f"~/{qos.AGENT_OBSERVATION}",
                                         lambda msg, a=a: self._on_agent_observation(a, msg), qos.STREAM)
                self.action_pubs[a] = node.create_publisher(AgentAction, f"~/{qos.AGENT_ACTION}", qos.STREAM)
                self.nodes.append(node)
        self.scenario_json = ""
        self.n_agents = 0
        self.expected = 0  # this host's agents that are in the team
        self.seed = 0
        self.wipeout_starts: frozenset[int] = frozenset()
        self.episodes = 0
        self.finished = False  # the current episode has ended (a done observation arrived)
        self._reset_steps()

    # ---------------------------------------------------------------------- episode
    def _reset_steps(self) -> None:
        self.collecting = -1  # step whose per-agent observations are being gathered
        self.gathered: dict[int, AgentObservation] = {}
        self.answered_step = -1
        self.answer_ids = np.zeros(0, dtype=np.int64)
        self.answer = np.zeros(0, dtype=np.int64)
        self.wiped_at = -1

    def _start_episode(self) -> None:
        self.team.reset(self.n_agents, self.seed)
        self._reset_steps()
        self.finished = False
        self.episodes += 1

    def _on_scenario(self, msg: ScenarioDescription) -> None:
        if msg.scenario_json == self.scenario_json or (scenario := read_scenario(msg, self.log)) is None:
            return
        self.scenario_json = msg.scenario_json
        self.n_agents = scenario.config.n_agents
        self.seed = scenario.seed
        self.wipeout_starts = frozenset(scenario.wipeout_starts)
        outside = self.ids[self.ids >= self.n_agents]
        if len(outside):
            self.log.error(f"agents {outside.tolist()} are not in this team of {self.n_agents}: "
                           "they get no observations")
        self.expected = int((self.ids < self.n_agents).sum())
        wrong = {k: v for k, v in self.world_needs.items() if getattr(scenario.config, k) != v}
        if wrong:
            self.log.error(f"this host's policies need a world with {wrong}, but the world serves "
                           f"{ {k: getattr(scenario.config, k) for k in wrong} }: `formic run` sets them")
        self._start_episode()
        self.log.info(f"scenario seed {self.seed}: driving agents {format_ids(self.ids.tolist())} ({self.transport})")

    def _ready(self, step: int, done: bool) -> bool:
        """Whether an observation of ``step`` should be answered (handles episode ends and a
        world that starts the same scenario again)."""
        if not self.scenario_json:
            return False  # the latched scenario has not arrived yet: the world re-sends
        if done:
            self.finished = True
            return False
        if self.finished and step == 0:
            self._start_episode()
        return not self.finished

    # ------------------------------------------------------------------- observations
    def _on_agent_observation(self, agent: int, msg: AgentObservation) -> None:
        if msg.agent_id != agent or not self._ready(msg.step, msg.done):
            return
        if msg.step == self.answered_step:
            self._resend(agent)
            return
        if msg.step < max(self.collecting, self.answered_step):
            return
        if msg.step > self.collecting:
            self.collecting, self.gathered = msg.step, {}
        self.gathered[agent] = msg
        if len(self.gathered) == self.expected:
            self._answer(convert.batch_from_agent_observations([self.gathered[a] for a in sorted(self.gathered)]))

    def _on_batch(self, msg: ObservationBatch) -> None:
        if not self._ready(msg.step, msg.done) or msg.step < self.answered_step:
            return
        ids = convert.read(msg.agent_ids, np.uint32).astype(np.int64)
        lookup = np.full(max(int(ids.max(initial=-1)), int(self.ids.max())) + 1, -1, dtype=np.int64)
        lookup[ids] = np.arange(len(ids))
        rows = lookup[self.ids]
        rows = rows[rows >= 0]
        if not len(rows):
            return  # none of ours (a re-send for other hosts' agents)
        if msg.step == self.answered_step:
            self.actions_pub.publish(convert.action_batch(msg.step, self.answer_ids, self.answer))
        elif len(rows) == len(ids) and (rows == np.arange(len(ids))).all():
            self._answer(convert.batch_from_observation_batch(msg))  # every row, in order: no copy
        else:
            self._answer(convert.batch_from_observation_batch(msg, rows))

    # ------------------------------------------------------------------------ actions
    def _answer(self, batch: AgentBatch) -> None:
        step = batch.step
        if step in self.wipeout_starts and self.wiped_at != step:
            self.team.wipe()
            self.wiped_at = step
        actions = self.team.act(batch)
        self.answered_step, self.answer_ids, self.answer = step, batch.agent_ids, actions
        self.collecting, self.gathered = -1, {}
        if self.transport == "batched":
            self.actions_pub.publish(convert.action_batch(step, batch.agent_ids, actions))
        else:
            for a, action in zip(batch.agent_ids.tolist(), actions.tolist()):
                self.action_pubs[a].publish(AgentAction(step=step, agent_id=a, action=action))

    def _resend(self, agent: int) -> None:
        row = np.flatnonzero(self.answer_ids == agent)
        if len(row):
            action = int(self.answer[row[0]])
            self.action_pubs[agent].publish(AgentAction(step=self.answered_step, agent_id=agent, action=action))


class WorldWatch:
    """Notices that the world which published our scenario has left the graph, so a ``--once``
    process that missed the final observation does not wait forever (checked every 0.5 s)."""

    PERIOD_S = 0.5

    def __init__(self, node: Node):
        self.node = node
        self.next_check = 0.0

    def gone(self, scenario_json: str) -> bool:
        now = time.monotonic()
        if not scenario_json or now < self.next_check:
            return False
        self.next_check = now + self.PERIOD_S
        return self.node.count_publishers(qos.SCENARIO) == 0


SWITCH_MODES = ("chunk", "episode")
WEIGHTS_WAIT_LOG_S = 10.0  # while a host waits for weights, it says so this often


class LearningHost:
    """A batched-transport host whose agents learn (distributed training).

    The agents act as the in-process trainer's do (:class:`LearningActor`: its network, LSTM
    states and sampler under the training filter, which needs the world's ``train_masks``:
    run the world with ``--training-masks``); each chunk of ``rollout_steps`` steps of the
    learning agents goes to the trainer as a Rollout. Weights come from the trainer's latched
    ``weights`` topic. ``switch="chunk"``: after each rollout the host waits for the weights
    that rollout produced and acts on with them, exactly as the in-process trainer updates
    after each chunk (on-policy; same seeds and settings give the same learning curve).
    ``switch="episode"``: an episode is played with one weights version while the trainer
    learns from its first chunks; at the next episode's start the host waits for the updates
    of all its rollouts and takes the newest weights (the trainer corrects for the lag with the
    behaviour version's outputs; with one host the lag stays below the chunks per episode).

    An episode starts at step 0 of a scenario the host has not played yet: observations of a
    new episode that arrive before its (latched) scenario are held until it does.
    """

    def __init__(self, agent_ids: list[int], cfg: TrainConfig, switch: str = "chunk", first_episode: int = 0,
                 namespace: str = qos.DEFAULT_NAMESPACE, name: str | None = None, torch_threads: int = 1):
        import torch
        from formic_interfaces.msg import Rollout, Weights
        from rclpy.qos import QoSProfile, ReliabilityPolicy

        from .trainer_node import ROLLOUT_DEPTH, ROLLOUTS, WEIGHTS, LearningActor

        if switch not in SWITCH_MODES:
            raise ValueError(f"unknown weights switch {switch!r}; choose from {', '.join(SWITCH_MODES)}")
        torch.set_num_threads(torch_threads)
        self.switch = switch
        self.control = rclpy.create_node(name or f"agent_host_{os.getpid()}", namespace=namespace)
        self.nodes = [self.control]
        self.log = self.control.get_logger()
        self.actor = LearningActor(cfg, agent_ids, host=self.control.get_name(), first_episode=first_episode)
        self.ids = self.actor.ids
        node = self.control
        node.create_subscription(ScenarioDescription, qos.SCENARIO, self._on_scenario, qos.LATCHED)
        node.create_subscription(ObservationBatch, qos.OBSERVATIONS, self._on_batch, qos.STREAM)
        node.create_subscription(Weights, WEIGHTS, self._on_weights, qos.LATCHED)
        self.actions_pub = node.create_publisher(ActionBatch, qos.ACTIONS, qos.STREAM)
        self.rollouts_pub = node.create_publisher(
            Rollout, ROLLOUTS, QoSProfile(depth=ROLLOUT_DEPTH, reliability=ReliabilityPolicy.RELIABLE))
        self.played = ""  # scenario of the episode being (or last) played
        self.next_scenario = ""  # a scenario not played yet
        self.scenario_json = ""  # the newest scenario seen (for WorldWatch)
        self.playing = False
        self.episodes = 0  # episodes finished
        self.episode_rollouts = 0  # rollouts sent in the current episode
        self.held: ObservationBatch | None = None  # newest observations not dealt with yet
        self.ready = None  # (AgentBatch, training masks) to act on once the weights allow
        self.newest = None  # the newest Weights message received
        self.wait_version: int | None = -1  # act only with weights newer than this (None: act now)
        self.answered_step, self.answer = -1, np.zeros(0, dtype=np.int64)
        self.waiting_since = time.monotonic()
        self.warned_masks = False

    # ------------------------------------------------------------------------ inputs
    def _on_scenario(self, msg: ScenarioDescription) -> None:
        if msg.scenario_json in (self.scenario_json, self.played) or (scenario := read_scenario(msg, self.log)) is None:
            return
        self.scenario_json = self.next_scenario = msg.scenario_json
        if (self.ids >= scenario.config.n_agents).any():
            self.log.error(f"agents {self.ids.tolist()} are not all in this team of {scenario.config.n_agents}")
        self.pump()

    def _on_weights(self, msg) -> None:
        if self.newest is None or msg.version > self.newest.version:
            self.newest = msg
            self.pump()

    def _on_batch(self, msg: ObservationBatch) -> None:
        self.held = msg
        self.pump()

    # ---------------------------------------------------------------------- stepping
    def _rows(self, msg: ObservationBatch) -> np.ndarray | None:
        """Rows of this host's agents in the message, in id order; None unless all are there."""
        ids = convert.read(msg.agent_ids, np.uint32).astype(np.int64)
        lookup = np.full(max(int(ids.max(initial=-1)), int(self.ids.max())) + 1, -1, dtype=np.int64)
        lookup[ids] = np.arange(len(ids))
        rows = lookup[self.ids]
        return rows if (rows >= 0).all() else None

    def _take(self, msg: ObservationBatch) -> bool:
        """Deal with a received observation batch; False to keep holding it (a new episode's
        step 0 before its scenario)."""
        rows = self._rows(msg)
        if rows is None:
            return True  # a re-send for other hosts' agents
        step = int(msg.step)
        if self.ready is not None and step == self.ready[0].step and not msg.done:
            return True  # a re-send of what waits for weights
        if self.playing and step == 0 and self.next_scenario and not msg.done:
            self.log.warning("a new episode started before this one ended: its last chunk is dropped")
            self.playing = False
        if self.playing and step == self.answered_step and not msg.done:
            self.actions_pub.publish(convert.action_batch(step, self.ids, self.answer))  # a re-send
            return True
        if not self.playing:
            if msg.done or step != 0:
                return True  # the end or the middle of an episode this host did not play
            if not self.next_scenario:
                return False
        elif step != self.answered_step + 1:
            return True  # stale
        if not len(msg.train_masks):
            if not self.warned_masks:
                self.log.error("the observations carry no training masks: run the world with --training-masks")
                self.warned_masks = True
            return True
        batch = convert.batch_from_observation_batch(msg, rows)
        if not self.playing:
            self._start_episode(batch)
        else:
            team_rewards = convert.read(msg.rewards, np.float32)  # every agent's: for team_reward
            rollout = self.actor.outcome(batch, team_rewards, rows, bool(msg.done))
            if rollout is not None:
                self.rollouts_pub.publish(rollout)
                self.episode_rollouts += 1
                if self.switch == "chunk":  # act on with the weights this rollout makes
                    self.wait_version, self.waiting_since = self.actor.version, time.monotonic()
                elif msg.done:  # start the next episode with the weights all of this one's make
                    self.wait_version = self.actor.version + self.episode_rollouts - 1
                    self.waiting_since = time.monotonic()
            if msg.done:
                self.playing = False
                self.episodes += 1
                return True
        masks = convert.read(msg.train_masks, np.uint8).reshape(-1, convert.ACTION_COUNT)[rows].astype(bool)
        self.ready = (batch, masks)
        return True

    def _start_episode(self, batch: AgentBatch) -> None:
        self.played, self.next_scenario = self.next_scenario, ""
        self.playing, self.answered_step, self.episode_rollouts = True, -1, 0
        self.actor.start_episode(batch.loads)

    def _weights_ready(self) -> bool:
        if self.wait_version is None:
            return True
        if self.newest is None or self.newest.version <= self.wait_version:
            if time.monotonic() - self.waiting_since > WEIGHTS_WAIT_LOG_S:
                self.log.warning(f"still waiting for weights newer than version {self.wait_version}")
                self.waiting_since = time.monotonic()
            return False
        self.actor.load_weights(self.newest)
        self.wait_version = None
        return True

    def pump(self) -> None:
        """Deal with what has arrived: the held observations, then acting when the weights allow."""
        if self.held is not None and self._take(self.held):
            self.held = None
        if self.ready is None or not self._weights_ready():
            return
        batch, masks = self.ready
        self.ready = None
        self.answer = self.actor.act(batch, masks)
        self.answered_step = batch.step
        self.actions_pub.publish(convert.action_batch(batch.step, self.ids, self.answer))


def serve_learning_agents(
    agent_ids: list[int],
    cfg: TrainConfig,
    switch: str = "chunk",
    first_episode: int = 0,
    namespace: str = qos.DEFAULT_NAMESPACE,
    name: str | None = None,
    episodes: int | None = None,
    domain_id: int | None = None,
    torch_threads: int = 1,
) -> int:
    """Host learning agents until interrupted (or until ``episodes`` episodes are played and
    their rollouts delivered, or the world is gone); returns the episodes played."""
    from rclpy.duration import Duration

    from .env import ros_session

    with ros_session(domain_id) as executor:
        host = LearningHost(agent_ids, cfg, switch=switch, first_episode=first_episode, namespace=namespace,
                            name=name, torch_threads=torch_threads)
        for node in host.nodes:
            executor.add_node(node)
        watch = WorldWatch(host.control)
        try:
            while not (episodes is not None and (host.episodes >= episodes or watch.gone(host.scenario_json))):
                executor.spin_once(timeout_sec=0.2)
                host.pump()  # also says so when the weights are late
            host.rollouts_pub.wait_for_all_acked(Duration(seconds=5.0))
        except KeyboardInterrupt:
            pass
        return host.episodes


def serve_agents(agent_ids: list[int], spec: str, once: bool = False, domain_id: int | None = None, **settings) -> int:
    """Host these agents (``settings``: :class:`AgentHost`'s) until interrupted (or, with
    ``once``, until an episode ends); returns the number of episodes played."""
    from .env import ros_session

    with ros_session(domain_id) as executor:
        host = AgentHost(agent_ids, spec, **settings)
        for node in host.nodes:
            executor.add_node(node)
        watch = WorldWatch(host.control)
        try:
            while not (once and (host.finished or watch.gone(host.scenario_json))):
                executor.spin_once(timeout_sec=0.2)
        except KeyboardInterrupt:
            pass
        return host.episodes
