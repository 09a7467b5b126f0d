"""The actor: a set of agents (team-wide ids, in order) acting under the training filter.

One LSTM state per agent, a torch sampler and a numpy stream of its own (the episode's
unfiltered agents under filter annealing, the "replace" filter's replacements), seeded anew
from the global episode number at every episode start (:func:`actor_streams`), so a resumed
run acts exactly as an uninterrupted one, and one rollout buffer for its
learning agents. The sampler and the annealing draws are team-wide (:func:`team_draws`): an
actor over some of the agents draws for every agent of the meta-agent worlds and keeps its
rows, so actors that split the agents between them sample what one actor over all of them
would (``formic train-ros --actors K``). Per episode :meth:`Actor.start_episode`; per step :meth:`Actor.act`, then
:meth:`Actor.reward`; at a chunk's end :meth:`Actor.rollout`: the :class:`Rollout` the learner
takes as it is. ``formic train`` runs one over all its worlds' agents, a ROS learning host one
over its agents.
"""

from __future__ import annotations

import numpy as np
import torch

from formic_agent.network import ForMICNet
from formic_world.geometry import N_ACTIONS

from .algorithm import sampling_mask
from .config import TrainConfig
from .rollout import Rollout
from .worlds import Frame


def actor_streams(cfg: TrainConfig, episode: int, first_agent: int = 0) -> tuple[torch.Generator, np.random.Generator]:
    """The torch sampler and the numpy stream of an actor in global episode ``episode`` whose
    first agent is ``first_agent``: both from seed sequences of (seed, episode, first agent), so
    no two of those share a stream (a sum such as seed + episode would: seed 8 at episode 4 and
    seed 9 at episode 3)."""
    key = [cfg.seed, int(episode), int(first_agent)]
    sampler_seed = int(np.random.SeedSequence([key[0], 6, *key[1:]]).generate_state(1, np.uint64)[0] >> np.uint64(1))
    generator = torch.Generator().manual_seed(sampler_seed)
    return generator, np.random.default_rng([key[0], 4, *key[1:]])


def step_food(loads_before: np.ndarray, loads_after: np.ndarray, load_full: int) -> float:
    """The food one step deposited at the nest, by :class:`formic_world.World`'s definition
    (``StepResult.food``: the load ticks unloaded there over ``load_full``), read from every
    agent's load (a fraction of ``load_full``) before and after the step, as observations carry
    them: loads fall only by unloading at the nest, and rounding them to whole ticks undoes the
    messages' float32, so this is the world's value to the bit."""
    before = np.rint(np.asarray(loads_before, dtype=np.float64) * load_full).astype(np.int64)
    after = np.rint(np.asarray(loads_after, dtype=np.float64) * load_full).astype(np.int64)
    return int(np.clip(before - after, 0, None).sum()) / load_full


def learning_rows(cfg: TrainConfig, ids: np.ndarray) -> np.ndarray:
    """Rows of ``ids`` (team-wide agent ids over the meta-agent worlds) whose agents learn:
    the first ``learning_agents`` of each world (all when it is None)."""
    ids = np.asarray(ids, dtype=np.int64)
    if cfg.learning_agents is None:
        return np.arange(len(ids))
    offsets = np.cumsum([0, *cfg.teams])
    world = np.clip(np.searchsorted(offsets, ids, side="right") - 1, 0, len(cfg.teams) - 1)
    return np.flatnonzero(ids - offsets[world] < cfg.learning_agents)


def filter_probability(cfg: TrainConfig, episode: int) -> float:
    """Probability that an agent-episode acts under the training filter: ``filter_initial`` up
    to ``filter_anneal_start``, then linearly to ``filter_final`` at ``filter_anneal_end``
    (no schedule, an end not after the start: ``filter_initial`` throughout)."""
    start, end, initial = cfg.filter_anneal_start, cfg.filter_anneal_end, cfg.filter_initial
    if end <= start:
        return initial
    fraction = min(max((episode - start) / (end - start), 0.0), 1.0)
    return initial + fraction * (cfg.filter_final - initial)


def team_draws(generator: torch.Generator, team: int, rows: np.ndarray) -> torch.Tensor:
    """Exp(1) draws for every action of a team of ``team`` agents, rows ``rows`` of them: a
    sample is the argmax of probability over draw, as ``torch.multinomial`` takes one sample
    (same generator, same draws, same actions: tested), whichever agents an actor holds."""
    return torch.empty(team, N_ACTIONS).exponential_(generator=generator)[torch.from_numpy(rows)]


def select_actions(cfg: TrainConfig, logits: torch.Tensor, train_mask: np.ndarray, generator: torch.Generator,
                   rng: np.random.Generator, sample_mask: np.ndarray | None = None,
                   team_rows: tuple[int, np.ndarray] | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Sample actions under the training filter. Returns (actions, log-probs, value_mask: False
    where the "replace" filter replaced the action). In "mask" mode ``sample_mask`` (default:
    ``sampling_mask``) says what may be sampled. ``team_rows``: (team size, the rows' team-wide
    ids) for team-wide draws (default: the rows are the team)."""
    if cfg.action_filter == "mask":
        allowed = sampling_mask(cfg, train_mask) if sample_mask is None else sample_mask
        logits = logits.masked_fill(~torch.from_numpy(allowed), -1e9)
    team, rows = team_rows or (len(logits), np.arange(len(logits)))
    actions = torch.argmax(torch.softmax(logits, -1) / team_draws(generator, team, rows), -1).numpy().copy()
    value_mask = np.ones(len(actions), dtype=bool)
    if cfg.action_filter == "replace":  # invalid samples are replaced by a random valid action
        rows = np.arange(len(actions))
        invalid = ~train_mask[rows, actions] & train_mask.any(1)
        for i in np.flatnonzero(invalid):
            actions[i] = rng.choice(np.flatnonzero(train_mask[i]))
        value_mask[invalid] = False
    logp = torch.log_softmax(logits, -1).gather(-1, torch.from_numpy(actions)[:, None])[:, 0]
    return actions, logp.numpy(), value_mask


class Actor:
    """``weights_version``: the version of the weights in ``net``, kept up to date by whoever changes them."""

    def __init__(self, cfg: TrainConfig, net: ForMICNet, agent_ids, weights_version: int = 0):
        self.cfg, self.net, self.weights_version = cfg, net, weights_version
        self.chunk_version = weights_version  # the weights that act in the current chunk
        self.ids = np.asarray(agent_ids, dtype=np.int64)
        self.learning = learning_rows(cfg, self.ids)
        self.team = sum(cfg.teams)  # the draws are team-wide (team_draws)
        if len(self.ids) and (self.ids.min() < 0 or self.ids.max() >= self.team):
            raise ValueError(f"agents {self.ids.tolist()} are not all in the team of {self.team} (teams={cfg.teams})")
        self.whole_team = np.array_equal(self.ids, np.arange(self.team))
        self.first_agent = int(self.ids[0]) if len(self.ids) else 0
        self.episode = 0
        self.generator: torch.Generator | None = None  # the episode's streams: set by start_episode
        self.rng: np.random.Generator | None = None
        self.replace_rng: np.random.Generator | None = None  # the "replace" filter's
        self.unfiltered = np.zeros(len(self.ids), dtype=bool)
        self.state = net.initial_state(len(self.ids))
        self.valid_rate: list[float] = []  # per step: share of free agents whose action was valid
        self._new_chunk()

    def __len__(self) -> int:
        """Steps in the current chunk."""
        return len(self.chunk["actions"])

    def start_episode(self, episode: int, schedule: int | None = None) -> None:
        """A new episode (global number ``episode``): fresh LSTM states, and which agents act
        unfiltered in it (filter annealing at ``schedule``, the schedule clock's episode; default
        ``episode``), and the episode's own random streams."""
        self.episode = episode
        self.generator, self.rng = actor_streams(self.cfg, episode)
        anneal_at = episode if schedule is None else schedule
        self.unfiltered = self.rng.random(self.team)[self.ids] >= filter_probability(self.cfg, anneal_at)
        # the replacements follow in team order, which no split reproduces: a part of the team
        # draws them from a stream of its own
        self.replace_rng = self.rng if self.whole_team else actor_streams(self.cfg, episode, self.first_agent)[1]
        self.state = self.net.initial_state(len(self.ids))
        self.valid_rate = []
        self._new_chunk()

    def _new_chunk(self) -> None:
        self.chunk: dict[str, list[np.ndarray]] = {key: [] for key in (
            "observations", "extra_inputs", "actions", "logprobs", "values", "rewards", "train_mask", "sample_mask",
            "loss_mask", "value_mask", "expert_actions", "imitation_mask")}
        h, c = self.state
        self.h0, self.c0 = h[:, self.learning].numpy().copy(), c[:, self.learning].numpy().copy()

    @torch.no_grad()
    def act(self, frame: Frame) -> np.ndarray:
        """Actions for every agent (rows as ``agent_ids``), sampled under the training filter."""
        if not len(self):
            self.chunk_version = self.weights_version
        observations = torch.from_numpy(np.ascontiguousarray(frame.observations))[None]
        logits, values, self.state = self.net(observations, self.state, torch.from_numpy(frame.extra_inputs)[None])
        allowed = sampling_mask(self.cfg, frame.train_mask)
        allowed[self.unfiltered] = True
        actions, logprobs, value_mask = select_actions(self.cfg, logits[0], frame.train_mask, self.generator,
                                                       self.replace_rng, sample_mask=allowed,
                                                       team_rows=(self.team, self.ids))
        free = ~frame.queued
        self.valid_rate.append(float(frame.action_mask[free, actions[free]].mean()) if free.any() else 1.0)
        step = {"observations": frame.observations, "extra_inputs": frame.extra_inputs,
                "actions": actions.astype(np.int64), "logprobs": logprobs, "values": values[0].numpy(),
                "train_mask": frame.train_mask, "sample_mask": allowed, "loss_mask": free, "value_mask": value_mask}
        for key, value in step.items():
            self.chunk[key].append(value[self.learning])
        return actions

    def demonstrate(self, expert_actions: np.ndarray, wanted: np.ndarray) -> None:
        """The demonstrator's actions of the last step and which of them are imitation targets."""
        self.chunk["expert_actions"].append(expert_actions[self.learning].astype(np.int64))
        self.chunk["imitation_mask"].append(wanted[self.learning].astype(bool))

    def reward(self, rewards: np.ndarray) -> None:
        """The rewards of the last step, every agent's (rows as ``agent_ids``), unscaled."""
        self.chunk["rewards"].append(np.asarray(rewards)[self.learning].astype(np.float32))

    @torch.no_grad()
    def rollout(self, frame: Frame, done: bool, food: float) -> Rollout:
        """The chunk's :class:`Rollout` of the learning agents, given what every agent sees after
        its last step (``frame``; its bootstrap value), whether that ends the episode and the food
        deposited during the chunk; and a new chunk."""
        rows = self.learning
        if len(self.chunk["rewards"]) != len(self) or not len(self):
            raise RuntimeError("a rollout needs at least one step, each with its rewards")
        self.chunk["observations"].append(frame.observations[rows])  # the last frame, for bootstrapping
        self.chunk["extra_inputs"].append(frame.extra_inputs[rows])
        _, next_value, _ = self.net(torch.from_numpy(np.ascontiguousarray(frame.observations))[None], self.state,
                                    torch.from_numpy(frame.extra_inputs)[None])
        arrays = {key: np.stack(values) for key, values in self.chunk.items() if values}
        rollout = Rollout(weights_version=self.chunk_version, episode=self.episode, done=done, food=float(food),
                          agent_ids=self.ids[rows], next_value=next_value[0].numpy()[rows], h0=self.h0, c0=self.c0,
                          **arrays)
        self._new_chunk()
        return rollout
