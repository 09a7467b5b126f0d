"""Agent host: one process that drives any set of agents over ROS.

Per-agent transport (default): every agent is its own rclpy node ``agent_K`` in the namespace,
with ``agent_K/observation`` in and ``agent_K/action`` out, all in one events executor (ROS
composition): what ``ros2 node list`` shows and what a robot's own node replaces. Batched: one
node holds the ``observations``/``actions`` pair and answers for its agents in one message.
Either way the host acts once per step for all its agents (a learned policy runs one batch) as
soon as it has all their observations of that step. Per-agent, an observation lost on a lossy
link does not stall the others: ``PARTIAL_WAIT_S`` after the step's first observation the host
acts for those that arrived and answers a late one on its own when it comes (policies draw
their randomness per agent and step, so the actions are the same either way).

Policies reset from the latched scenario (seed, team size), so a restarted host starts with
fresh memory and answers from whatever step the world is at. Observations of a step already
answered (the world re-sends step 0 until everyone is heard) get the same actions again, never
a second policy call. Learning mode (batched; distributed training): :mod:`formic_ros.drivers.learning_host`.
"""

from __future__ import annotations

import os
import time
from contextlib import suppress

import numpy as np
from formic_interfaces.msg import (ActionBatch, AgentAction, AgentObservation, ObservationBatch,
                                   ScenarioDescription)
from rclpy.node import Node

from formic_agent.policy import AgentBatch, CentralPolicy
from formic_runtime.registry import world_overrides
from formic_runtime.team import Team, format_ids
from formic_runtime.threads import configure_threads
import formic_topics as topics
from formic_world import Scenario

from .. import convert, qos
from ..env import deliver_last_messages
from ..intake import Intake, lean_node, not_dispatched
from ..parameters import declare_settings
from ..timeline import Timeline
from .claim import Claim
from .protocol import DriverProtocol, Turn
from .world_watch import WorldWatch, read_scenario

TRANSPORTS = ("per-agent", "batched")
PARTIAL_WAIT_S = 0.1  # per-agent: act for the agents heard this long after a step's first observation
POLL_S = 0.003  # batched, one host for the whole team: after answering, look for the next step without sleeping
BLOCK_S = 0.2  # otherwise, how long the executor waits for a message before the loop looks around
INTAKE_CHUNK = 16  # per agent, with an intake: the host wakes when this many more observations are there
# (128 learned agents: taken all after the last, they held the step 1.25-1.37 ms after the world's last
# publish, as the executor's one by one did; 32 at a time 0.89-1.00 ms, 16 0.67-0.87, 8 0.77-0.88)
INTAKE_WAIT_S = 0.005  # and its other events run this often at least


class AgentHost(Node):
    """One host's control node (its settings, the scenario, the batched transport) with the
    policies of its agents; per agent a lean node of its own on the per-agent transport. Add
    :attr:`nodes` (itself first) to an executor and spin."""

    def __init__(self, agent_ids: list[int], spec: str, model: str | None = None, greedy: bool = False,
                 transport: str = "per-agent", namespace: str = topics.DEFAULT_NAMESPACE,
                 name: str | None = None, threads: int = 1, intake: bool = True):
        if transport not in TRANSPORTS:
            raise ValueError(f"unknown transport {transport!r}; choose from {', '.join(TRANSPORTS)}")
        self.ids = np.array(sorted(agent_ids), dtype=np.int64)
        self.team = Team.for_agents(spec, self.ids.tolist())
        self.world_needs = world_overrides(self.team.names)  # csaf-ref: one-slot queues
        configure_threads(threads)
        for policy, _ in self.team.build(model=model, greedy=greedy).members:
            if isinstance(policy, CentralPolicy):
                raise ValueError(f"{policy.name} needs the full world: it runs as its own node")
        self.transport = transport
        super().__init__(name or f"agent_host_{os.getpid()}", namespace=namespace)
        declare_settings(self, {"agent_ids": self.ids.tolist(), "policy": spec, "model": model,
                                        "greedy": greedy, "transport": transport, "threads": threads})
        self.log = self.get_logger()
        self.nodes = [self]  # what the executor spins
        self.agent_nodes: list[Node] = []  # per agent: agent_K, its observation in and action out
        self.observation_intake: Intake | None = None  # per agent: taken by spin_once (formic_ros.intake)
        self.create_subscription(ScenarioDescription, topics.SCENARIO, self._on_scenario, qos.LATCHED)
        if transport == "batched":
            self.create_subscription(ObservationBatch, topics.OBSERVATIONS, self._on_batch, qos.STREAM)
            self.actions_pub = self.create_publisher(ActionBatch, f"~/{topics.ACTIONS}", qos.STREAM_WRITER)
            batched, publishers = self.actions_pub.topic_name, [self.actions_pub]
        else:
            self.action_pubs, readers = {}, []
            for a in self.ids.tolist():
                node = lean_node(topics.agent_node_name(a), namespace)
                on_observation = not_dispatched if intake else lambda data, a=a: self._on_agent_observation(a, data)
                readers.append(node.create_subscription(AgentObservation, f"~/{topics.AGENT_OBSERVATION}",
                                                        on_observation, qos.LATEST, raw=True))  # bytes: decoded per step
                self.action_pubs[a] = node.create_publisher(AgentAction, f"~/{topics.AGENT_ACTION}", qos.STREAM_WRITER)
                self.agent_nodes.append(node)
            if intake:
                self.observation_intake = Intake(readers, self.context)
            else:
                self.nodes += self.agent_nodes
            self.create_timer(PARTIAL_WAIT_S / 4, self._answer_late_step)
            batched, publishers = None, list(self.action_pubs.values())
        self.claim = Claim(self, self.ids.tolist(), batched, publishers=publishers)  # the world checks it
        self.protocol = DriverProtocol(whole_episodes=False)
        self.scenario: Scenario | None = None
        self.horizon = -1  # its episode's steps (-1: no scenario yet)
        self.expected = 0  # this host's agents that are in the team
        self.episodes = 0
        self.answered_at = -np.inf  # when the last answer went out (monotonic s)
        self.timeline = Timeline("host")  # FORMIC_TIMELINE: where each step's time goes
        self.rows = list(range(len(self.ids)))  # the intake's readers, in agent order
        self._reset_steps()
        self.log.info(f"up: agents {format_ids(self.ids.tolist())} ({transport}), waiting for a world in {namespace}")

    def destroy_node(self) -> None:
        self.timeline.save()
        if self.observation_intake is not None:  # agent nodes no executor holds: their last actions, then them
            deliver_last_messages(self.agent_nodes)
            for node in self.agent_nodes:
                node.destroy_node()
        super().destroy_node()

    def spin_once(self, executor, timeout_s: float) -> None:
        """One turn of the host's loop. Without an intake, the executor's next event (waiting
        ``timeout_s`` at most). With one, the observations waiting are taken, then the host
        sleeps until ``INTAKE_CHUNK`` more of those it expects are there (the world publishes in
        agent order; ``INTAKE_WAIT_S`` at most) and takes them, and the executor runs what is ready."""
        intake = self.observation_intake
        if intake is None or self.expected == 0:
            executor.spin_once(timeout_sec=timeout_s)
            if intake is None:
                return
        self._sweep()
        if self.expected:
            intake.wait(min(len(self.gathered) + INTAKE_CHUNK, self.expected) - 1, min(timeout_s, INTAKE_WAIT_S))
            self._sweep()
            executor.spin_ready()

    def _sweep(self) -> None:
        for row, data in self.observation_intake.sweep(self.rows):
            self._on_agent_observation(int(self.ids[row]), data)

    @property
    def finished(self) -> bool:
        """Whether the current episode has ended (its done observation arrived)."""
        return self.protocol.ended

    @property
    def answered_step(self) -> int:
        return self.protocol.answered_step

    def wait_s(self) -> float:
        """How long the executor may sleep waiting for the next message. Not at all for
        ``POLL_S`` after a batched answer for the whole team, while the world steps (2-3 ms at
        128 agents): a host that sleeps through it loses its core to whatever else runs, and its
        next forward pass starts on cold caches (10.3 against 8.9 ms a step, 128 learned agents,
        two nice-19 trainings on the 2 cores; +10% steps/s). Per agent the observations wake the
        host anyway (no gain measured), and several polling hosts would take the cores the world
        needs, so only a host that drives every agent of a batched world polls."""
        whole_team = self.scenario is not None and self.expected == self.scenario.config.n_agents
        polling = self.transport == "batched" and whole_team and time.monotonic() - self.answered_at < POLL_S
        return 0.0 if polling else BLOCK_S

    # ---------------------------------------------------------------------- episode
    def _reset_steps(self) -> None:
        self.collecting = -1  # step whose per-agent observations are being gathered
        self.gathered: dict[int, bytes] = {}  # agent -> its serialized observation (convert.agent_observation_head)
        self.gathering_since = 0.0  # when the first of them arrived
        self.answer_ids = np.zeros(0, dtype=np.int64)
        self.answer = np.zeros(0, dtype=np.int64)
        self.wiped_at = -1

    def _start_episode(self) -> None:
        self.team.reset(self.scenario.config.n_agents, self.scenario.seed)
        self._reset_steps()
        self.episodes += 1

    def _on_scenario(self, msg: ScenarioDescription) -> None:
        if msg.scenario_json == self.protocol.newest or (scenario := read_scenario(msg, self.log)) is None:
            return
        self.scenario, config = scenario, scenario.config
        self.horizon = config.episode_steps
        outside = self.ids[self.ids >= config.n_agents]
        if len(outside):
            self.log.error(f"agents {outside.tolist()} are not in this team of {config.n_agents}: "
                           "they get no observations")
        self.expected = int((self.ids < config.n_agents).sum())
        wrong = {k: v for k, v in self.world_needs.items() if getattr(config, k) != v}
        if wrong:
            self.log.error(f"this host's policies need a world with {wrong}, but the world serves "
                           f"{ {k: getattr(config, k) for k in wrong} }: `formic run` sets them")
        if self.protocol.scenario(msg.scenario_json):
            self._start_episode()
        self.log.info(f"scenario seed {scenario.seed}: driving agents {format_ids(self.ids.tolist())} "
                      f"({self.transport})")

    def _turn(self, step: int, done: bool) -> Turn:
        """The protocol's turn for an observation (none before the world confirmed this host's
        claim and the recorders matched it: the world re-sends)."""
        if not self.claim.ready():
            return Turn.IGNORE
        turn = self.protocol.receive(step, done)
        if turn is Turn.START:  # the world plays the scenario again
            self._start_episode()
        return turn

    # ------------------------------------------------------------------- observations
    def _on_agent_observation(self, agent: int, data: bytes) -> None:
        head = convert.agent_observation_head(data)
        if head is None:
            self.log.warning(f"agent {agent}: an observation that does not decode", throttle_duration_sec=5.0)
            return
        data, step, agent_id, done = head
        if agent_id != agent:
            return
        turn = self._turn(step, done)
        if turn is Turn.RESEND:
            if agent in self.answer_ids:  # a re-send
                action = int(self.answer[self.answer_ids == agent][0])
                self.action_pubs[agent].publish(convert.agent_action_bytes(step, agent, action))
            else:  # late: the others were answered without it
                self._answer(convert.decode_agent_observation_bytes([data]))
            return
        if turn not in (Turn.START, Turn.STEP) or step < self.collecting:
            return
        if step > self.collecting:
            self.collecting, self.gathered, self.gathering_since = step, {}, time.monotonic()
        self.gathered[agent] = data
        if len(self.gathered) == self.expected:
            self._answer_gathered()

    def _answer_gathered(self) -> None:
        self.timeline.mark("all_in", self.collecting)
        self._answer(convert.decode_agent_observation_bytes([self.gathered[a] for a in sorted(self.gathered)]))

    def _answer_late_step(self) -> None:
        """Timer: act for the agents heard when the rest of the step is late (a lost message)."""
        if self.gathered and time.monotonic() - self.gathering_since >= PARTIAL_WAIT_S:
            self.log.warning(f"step {self.collecting}: acting for {len(self.gathered)} of {self.expected} agents; "
                             "the others' observations are late", throttle_duration_sec=5.0)
            self._answer_gathered()

    def _on_batch(self, msg: ObservationBatch) -> None:
        turn = self._turn(msg.step, msg.done)
        if turn not in (Turn.START, Turn.STEP, Turn.RESEND):
            return
        if turn is not Turn.RESEND:
            self.timeline.mark("all_in", msg.step)
        rows = convert.rows_of(msg, self.ids)
        rows = rows[rows >= 0]
        if not len(rows):
            return  # none of ours (a re-send for other hosts' agents)
        if turn is Turn.RESEND:
            self.actions_pub.publish(convert.encode_actions(msg.step, self.answer_ids, self.answer))
        elif len(rows) == len(msg.agent_ids) and (rows == np.arange(len(rows))).all():
            self._answer(convert.decode_observation_batch(msg))  # every row, in order: no copy
        else:
            self._answer(convert.decode_observation_batch(msg, rows))

    # ------------------------------------------------------------------------ actions
    def _answer(self, batch: AgentBatch) -> None:
        step = batch.step
        if step in self.scenario.wipeout_starts and self.wiped_at != step:
            self.team.wipe()
            self.wiped_at = step
        self.timeline.mark("decide", step)
        actions = self.team.act(batch)
        self.timeline.mark("decided", step)
        if step == self.protocol.answered_step:  # a late agent of a step answered in part
            self.answer_ids = np.concatenate([self.answer_ids, batch.agent_ids])
            self.answer = np.concatenate([self.answer, actions])
        else:
            self.protocol.answered(step)
            self.answer_ids, self.answer = batch.agent_ids, actions
        self.collecting, self.gathered = -1, {}
        if self.transport == "batched":
            self.actions_pub.publish(convert.encode_actions(step, batch.agent_ids, actions))
        else:
            for a, action in zip(batch.agent_ids.tolist(), actions.tolist()):  # serialized here: no message objects
                self.action_pubs[a].publish(convert.agent_action_bytes(step, a, action))
        self.answered_at = time.monotonic()
        self.timeline.mark("answered", step)


def serve_agents(agent_ids: list[int], spec: str, once: bool = False, domain_id: int | None = None, **settings) -> int:
    """Host these agents (``settings``: :class:`AgentHost`'s) until interrupted (or, with
    ``once``, until an episode ends); returns the number of episodes played."""
    from ..env import ros_session

    with ros_session(domain_id) as executor:
        host = AgentHost(agent_ids, spec, **settings)
        for node in host.nodes:
            executor.add_node(node)
        watch = WorldWatch(host)
        with suppress(KeyboardInterrupt):
            while not (once and host.finished):
                host.spin_once(executor, host.wait_s())
                if once and not host.finished and watch.ended(host.answered_step + 1, host.horizon):
                    break  # only the final (done) observation was lost
        return host.episodes
