"""The training worlds: scenarios per episode set (also the ROS world node's), the frames an
actor reads (:func:`make_frame`, also the ROS learning host's), and the meta-agent worlds
stepped together with their demonstrators."""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from formic_agent.inputs import ActionFeedback, extra_inputs, nest_features
from formic_agent.policy import AgentBatch
from formic_runtime.registry import make_policy
from formic_world import Scenario, World, WorldConfig, generate_scenario
from formic_world.pheromones import curriculum_intensities

from .config import TrainConfig, reward_config


class Frame(NamedTuple):
    """What agents (rows) see at one step: observations, extra inputs (odometry, own action
    feedback), valid actions (the environment's, the training filter's), queued or not, and the
    rewards of the step that led here (mixed with the team mean when ``team_reward`` > 0)."""

    observations: np.ndarray
    extra_inputs: np.ndarray
    action_mask: np.ndarray
    train_mask: np.ndarray
    queued: np.ndarray
    rewards: np.ndarray


def make_frame(cfg: TrainConfig, batch: AgentBatch, train_mask: np.ndarray, feedback: ActionFeedback,
               team_rewards: np.ndarray, rows=slice(None)) -> Frame:
    """The frame of ``batch``'s agents, whose last actions ``feedback`` knows. ``team_rewards``:
    every agent's of their world (the team mean needs them all), ``rows``: the batch's among them.
    The one builder of the in-process training worlds and the ROS learning host."""
    extra = extra_inputs(nest_features(batch.positions, batch.loads, batch.world_shape),
                         feedback.features(batch.agent_ids, batch.positions, batch.queued))
    rewards = np.asarray(share_rewards(team_rewards, cfg.team_reward))[rows].astype(np.float32)
    return Frame(batch.observations, extra, batch.action_mask, train_mask, np.asarray(batch.queued, dtype=bool),
                 rewards)


def scenario_rng(cfg: TrainConfig, episode: int) -> np.random.Generator:
    """The scenario stream of global ``episode`` (each episode set draws from its own)."""
    return np.random.default_rng([cfg.seed, 3, episode])


def sample_scenarios(cfg: TrainConfig, rng: np.random.Generator,
                     episode: int) -> tuple[list[Scenario], float, float]:
    """One episode set's scenarios, one per meta-agent world (random side, obstacle density
    and seed, drawn from ``rng`` in that order), with the curriculum's pheromone intensities
    at global ``episode``. Returns (scenarios, highway intensity, deposit strength). The
    in-process trainer and the ROS world node (distributed training) both draw from here."""
    if cfg.curriculum and cfg.pheromones:
        highway, deposit = curriculum_intensities(episode, cfg.curriculum_start, cfg.curriculum_end)
    else:
        highway, deposit = 0.0, 1.0
    scenarios, rewards = [], reward_config(cfg)
    for team, (lo, hi) in zip(cfg.teams, cfg.world_sizes):
        side = 2 * int(rng.integers(lo // 2, hi // 2 + 1))
        config = WorldConfig(
            height=side, width=side, n_agents=team,
            obstacle_density=float(rng.uniform(*cfg.obstacle_range)),
            episode_steps=cfg.episode_steps, view_size=cfg.view_size,
            highway_intensity=highway, deposit_strength=deposit,
            pheromones_visible=cfg.pheromones, training_start=cfg.training_start,
            training_filter=cfg.training_filter, rewards=rewards,
        )
        scenarios.append(generate_scenario(config, int(rng.integers(2**31))))
    return scenarios, highway, deposit


def share_rewards(rewards: np.ndarray, fraction: float) -> np.ndarray:
    """Mix one world's per-agent rewards with their mean (``team_reward``), in float32 as the ROS
    observation messages carry rewards, so distributed training mixes exactly the same."""
    if fraction == 0.0:
        return rewards
    team = np.asarray(rewards, dtype=np.float32)
    return np.float32(1.0 - fraction) * team + np.float32(fraction) * team.mean(dtype=np.float32)


class MetaAgents:
    """All training worlds, stepped together so one forward pass serves every agent."""

    def __init__(self, cfg: TrainConfig):
        self.cfg = cfg
        self.worlds: list[World] = []
        self.offsets = np.cumsum([0, *cfg.teams])
        self.n_agents = int(self.offsets[-1])
        self.experts: list = []  # one demonstrator per world (cfg.imitate)
        self.feedback = [ActionFeedback(team) for team in cfg.teams]
        self.rewards: list[np.ndarray] = []  # each world's last step's (zeros at an episode's start)
        self._seen: list[tuple[np.ndarray, np.ndarray]] = []  # each world's last (observations, valid)

    def reset(self, episode: int, schedule: int | None = None) -> None:
        """New scenarios for every world, drawn from the episode's own stream (a resumed run
        draws what an uninterrupted one would); curriculum intensities at ``schedule`` (the
        schedule clock's episode; default the global episode)."""
        scenarios, self.highway, self.deposit = sample_scenarios(
            self.cfg, scenario_rng(self.cfg, episode), episode if schedule is None else schedule)
        self.worlds = [World(scenario) for scenario in scenarios]
        for feedback, team in zip(self.feedback, self.cfg.teams):
            feedback.reset(team)
        self.rewards = [np.zeros(team) for team in self.cfg.teams]
        if self.cfg.imitate is not None:
            self.experts = [make_policy(self.cfg.imitate) for _ in scenarios]
            for expert, scenario in zip(self.experts, scenarios):
                expert.reset(scenario.config.n_agents, scenario.seed)

    def observe(self) -> Frame:
        """What every agent of every world sees now (rows: team-wide ids)."""
        self._seen = [(w.observer.observe(), w.action_mask()) for w in self.worlds]
        frames = [make_frame(self.cfg, AgentBatch.from_world(w, observations=obs, action_mask=valid),
                             w.training_action_mask(valid), feedback, rewards)
                  for w, (obs, valid), feedback, rewards in zip(self.worlds, self._seen, self.feedback, self.rewards)]
        return Frame(*map(np.concatenate, zip(*frames)))

    def demonstrations(self) -> tuple[np.ndarray, np.ndarray]:
        """(expert action, whether it is an imitation target) for every agent of every world,
        from the last observations; the experts must see every step to keep their state."""
        cfg, targets, wanted = self.cfg, [], []
        radius = np.inf if cfg.imitation_radius is None else cfg.imitation_radius
        for w, expert, (obs, valid) in zip(self.worlds, self.experts, self._seen):
            targets.append(expert.act(AgentBatch.from_world(w, observations=obs, action_mask=valid)))
            near = np.abs(w.pos - (np.array(w.grid.shape) / 2 - 0.5)).max(axis=1) <= radius
            who = w.carrying if cfg.imitation_agents == "loaded" else np.ones(len(w.pos), bool)
            wanted.append(near & who & ~w.queued)
        return np.concatenate(targets), np.concatenate(wanted)

    def step(self, actions: np.ndarray) -> np.ndarray:
        """Every world steps with its agents' ``actions``; returns the food each deposited (the
        rewards come with the next frame)."""
        food = []
        for i, (w, lo, hi) in enumerate(zip(self.worlds, self.offsets[:-1], self.offsets[1:])):
            self.feedback[i].record(np.arange(hi - lo), actions[lo:hi], w.pos, w.queued)
            result = w.step(actions[lo:hi])
            self.rewards[i] = result.rewards
            food.append(result.food)
        return np.array(food)
