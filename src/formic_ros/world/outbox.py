"""What the world node publishes, and when: the scenario and summary (latched), observations
(batched, and per agent only to the agents whose topic has a subscriber), applied actions, state
and clock (only while someone subscribes), and the viewers' map, markers and score every k steps."""

from __future__ import annotations

import time
from collections.abc import Callable

import numpy as np
from formic_interfaces.msg import (ActionBatch, AgentObservation, ObservationBatch, ScenarioDescription,
                                   WorldState)
from std_msgs.msg import Float64, String

from formic_agent.policy import AgentBatch
import formic_topics as topics
from formic_world import StepResult, World
from formic_world.metric_frame import MetricFrame

from .. import convert, qos
from . import viewer_msgs
from .options import WorldNodeOptions

LISTENER_REFRESH_S = 0.25  # how often the set of per-agent observation subscribers is re-read
LINGER_S = 0.5  # the node stays up at most this long after the episode's last messages
LINGER_POLL_S = 0.02  # how often it looks whether their readers have left


class WorldOutbox:
    """The world node's publishers (``node``: the world node; ``metric_frame()``: where the
    current grid lies, for the viewers)."""

    def __init__(self, node, n_agents: int, options: WorldNodeOptions, metric_frame: Callable[[], MetricFrame]):
        self.options, self.metric_frame = options, metric_frame
        pub = node.create_publisher
        self.scenario_pub = pub(ScenarioDescription, topics.SCENARIO, qos.LATCHED)
        self.summary_pub = pub(String, topics.SUMMARY, qos.LATCHED)
        self.observations_pub = pub(ObservationBatch, topics.OBSERVATIONS, qos.STREAM_WRITER)
        self.state_pub = pub(WorldState, topics.STATE, qos.LOG)
        self.applied_pub = pub(ActionBatch, topics.APPLIED_ACTIONS, qos.LOG)
        self.score_pub = pub(Float64, topics.SCORE, qos.LOG)
        self.clock_pub = pub(viewer_msgs.Clock, topics.CLOCK, qos.LOG)
        self.map_pub = pub(viewer_msgs.OccupancyGrid, topics.MAP, qos.VIEWER)
        self.markers_pub = pub(viewer_msgs.MarkerArray, topics.AGENT_MARKERS, qos.VIEWER)
        self.agent_obs_pubs = [pub(AgentObservation, topics.agent_topic(a, topics.AGENT_OBSERVATION), qos.STREAM_WRITER)
                               for a in range(n_agents)]
        self.by_topic = {topics.STATE: self.state_pub, topics.APPLIED_ACTIONS: self.applied_pub,
                         topics.OBSERVATIONS: self.observations_pub, topics.SUMMARY: self.summary_pub,
                         topics.SCENARIO: self.scenario_pub, topics.SCORE: self.score_pub}  # require_subscribers
        self.everything = [self.scenario_pub, self.summary_pub, self.state_pub, self.applied_pub,
                           self.observations_pub, self.score_pub, self.clock_pub, self.map_pub, self.markers_pub,
                           *self.agent_obs_pubs]  # what a recorder must match before step 0
        self._listening: list[int] = []
        self._listening_at = -np.inf

    def relisten(self) -> None:
        """Read the per-agent listeners afresh at the next observations."""
        self._listening_at = -np.inf

    def _listeners(self) -> list[int]:
        now = time.monotonic()
        if now - self._listening_at > LISTENER_REFRESH_S:
            self._listening = [a for a, p in enumerate(self.agent_obs_pubs) if p.get_subscription_count() > 0]
            self._listening_at = now
        return self._listening

    def observations(self, world: World, result: StepResult, missing: np.ndarray | None = None) -> None:
        """Observations of the current step; ``missing`` (a mask): a re-send, only to the
        agents that have not answered yet (it also re-reads who listens)."""
        if missing is not None:
            self.relisten()
        batch = AgentBatch.from_world(world, observations=result.observations, action_mask=result.action_mask)
        if self.observations_pub.get_subscription_count() > 0:
            train = world.training_action_mask(result.action_mask) if self.options.training_masks else None
            rows = None if missing is None else np.flatnonzero(missing)
            self.observations_pub.publish(convert.encode_observation_batch(
                batch, result.rewards, result.done, rows=rows, train_masks=train,
                encoding=self.options.observation_encoding))
        listening = self._listeners()
        if missing is not None:
            listening = [a for a in listening if missing[a]]
        if listening:  # rows as the batch has them (agent ids 0..N-1) when every agent listens: no copies
            rows = None if len(listening) == len(self.agent_obs_pubs) else np.asarray(listening, dtype=np.int64)
            for a, data in zip(listening, convert.agent_observation_bytes(batch, result.rewards, result.done, rows)):
                self.agent_obs_pubs[a].publish(data)

    def applied(self, t: int, actions: np.ndarray) -> None:
        """What step ``t`` applied (volatile: nobody can read it later, so only to a subscriber)."""
        if self.applied_pub.get_subscription_count():
            self.applied_pub.publish(convert.encode_applied(t, actions))

    def state(self, world: World, missed: np.ndarray, final: bool = False) -> None:
        """State and clock (volatile: built only while someone subscribes, as building the
        state costs more than the rest of a step's messages), viewers every k steps (latched:
        skipped while nobody subscribes, but the last step always goes out)."""
        every = self.options.viewer_every
        if self.state_pub.get_subscription_count():
            self.state_pub.publish(convert.encode_state(world, missed))
        if self.clock_pub.get_subscription_count():
            self.clock_pub.publish(viewer_msgs.clock(world.t, self.options.dt))
        viewers = (self.score_pub, self.map_pub, self.markers_pub)
        if every > 0 and (final or world.t % every == 0 and any(p.get_subscription_count() for p in viewers)):
            stamp = viewer_msgs.sim_time(world.t, self.options.dt)
            self.score_pub.publish(Float64(data=world.score))
            self.map_pub.publish(viewer_msgs.occupancy_grid(world, stamp, self.metric_frame()))
            self.markers_pub.publish(viewer_msgs.agent_markers(world, stamp, self.metric_frame()))

    def linger(self, executor) -> None:
        """Keep the node up after the last messages until their readers have left (a host
        leaves once it has read the done observation), at most ``LINGER_S``: a process that
        exits at once sometimes takes its final samples with it (seen with the done
        observations). A reader that stays (a recorder, a viewer) gets the whole ``LINGER_S``."""
        until = time.monotonic() + LINGER_S
        streams = [self.observations_pub, self.score_pub, self.clock_pub, self.map_pub, self.markers_pub,
                   *self.agent_obs_pubs]
        while (now := time.monotonic()) < until and any(p.get_subscription_count() for p in streams):
            executor.spin_once(timeout_sec=min(LINGER_POLL_S, until - now))
