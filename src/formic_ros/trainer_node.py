"""The trainer node: Rollout messages in, the in-process trainer's own update, Weights out.

Learning state is a :class:`formic_trainer.train.Trainer` (same network initialisation,
optimiser, update order, checkpoints, TensorBoard logs and resume as ``formic train``); each
rollout is one call of :func:`formic_trainer.train.update`, and every update is broadcast as
a new weights version (the number of updates so far; reliable, transient-local: a host that
starts late gets the newest), identified by a hash of its bytes.

A Rollout carries what the environment produced (observations, actions, rewards, masks); the
node recomputes what the network said at the time (log-probabilities, values, the bootstrap
value) by running the weights version that chose the actions (``weights_version``) over the
observations step by step, as the host did, so PPO's ratio is taken against the behaviour
policy. Recent versions are kept for that (``max_lag``); older rollouts are dropped. An
episode sent in several chunks continues its LSTM state from the previous chunk. The hosts
also send what only they know exactly: the sampling masks their agents acted under (with
several hosts the trainer cannot re-draw which agents acted unfiltered) and, for networks with
the odometry input (``nest_input``), those inputs.

The hosts' side is here too: :class:`RolloutCollector` builds Rollout messages and
:class:`LearningActor` acts as the in-process trainer does (its network, sampler and random
streams), so one host with the whole team and the trainer node reproduce ``formic train``.
"""

from __future__ import annotations

import copy
import dataclasses
import hashlib
import json
import signal
import time
from collections import OrderedDict, deque
from collections.abc import Callable
from pathlib import Path

import numpy as np
import torch

from formic_agent.checkpoint import CheckpointError, read_checkpoint, state_dict_bytes
from formic_agent.network import (
    N_ACTIONS,
    N_EXTRA_INPUTS,
    NETWORK_PRESETS,
    ForMICNet,
    NetworkConfig,
    nest_features,
)
from formic_agent.policy import AgentBatch
from formic_trainer.train import (
    TrainConfig,
    Trainer,
    filter_probability,
    sampling_mask,
    select_actions,
    set_learning_rate,
    share_rewards,
    update,
)

ROLLOUTS = "rollouts"
WEIGHTS = "weights"
ROLLOUT_DEPTH = 16
DEFAULT_MAX_LAG = 4  # weights versions a rollout may lag behind and still be learned from
SAMPLER_STRIDE = 1_000_003  # sampler seeds of hosts whose first agents differ never meet


# ----------------------------------------------------------------------------- hosts' side
class RolloutCollector:
    """What an agent host accumulates for the trainer about its learning agents, one step at
    a time, and turns into a Rollout message (arrays are time-major, rows like ``agent_ids``).

    Per step: :meth:`add_step` when the actions are chosen, :meth:`add_rewards` when the next
    observations (which carry the rewards of that step) arrive. At the end of a chunk,
    :meth:`to_message` with the observations that follow it (for bootstrapping).
    """

    def __init__(self, agent_ids, host: str = "", episode: int = 0, weights_version: int = 0):
        self.agent_ids = np.asarray(agent_ids, dtype=np.uint32)
        self.host, self.episode, self.weights_version = host, int(episode), int(weights_version)
        self.observations: list[np.ndarray] = []
        self.actions: list[np.ndarray] = []
        self.rewards: list[np.ndarray] = []
        self.train_masks: list[np.ndarray] = []
        self.loss_mask: list[np.ndarray] = []
        self.value_mask: list[np.ndarray] = []
        self.sample_masks: list[np.ndarray] = []
        self.extra: list[np.ndarray] = []

    def __len__(self) -> int:
        return len(self.actions)

    def add_step(self, observations: np.ndarray, train_masks: np.ndarray, queued: np.ndarray,
                 actions: np.ndarray, value_mask: np.ndarray | None = None, sample_mask: np.ndarray | None = None,
                 extra: np.ndarray | None = None) -> None:
        """One decision: observations (A, C, V, V), training masks (A, 5), queued (A,) (a
        queued agent's step is masked out of the losses), actions (A,), value_mask (A,) (0
        where the action filter replaced the sampled action), and optionally the sampling mask
        (A, 5) and the odometry inputs (A, 4) (give them at every step or never)."""
        if sample_mask is not None:
            self.sample_masks.append(np.asarray(sample_mask, dtype=bool))
        if extra is not None:
            self.extra.append(np.asarray(extra, dtype=np.float32))
        self.observations.append(np.asarray(observations, dtype=np.float32))
        self.train_masks.append(np.asarray(train_masks, dtype=bool))
        self.loss_mask.append(~np.asarray(queued, dtype=bool))
        self.actions.append(np.asarray(actions))
        self.value_mask.append(np.ones(len(self.agent_ids), bool) if value_mask is None
                               else np.asarray(value_mask, dtype=bool))

    def add_rewards(self, rewards: np.ndarray) -> None:
        """The rewards of the last step (A,), as the environment gave them (unscaled)."""
        if len(self.rewards) != len(self.actions) - 1:
            raise RuntimeError("add_rewards must follow add_step, once per step")
        self.rewards.append(np.asarray(rewards, dtype=np.float32))

    def arrays(self, last_observations: np.ndarray, last_extra: np.ndarray | None = None) -> dict[str, np.ndarray]:
        """The chunk as arrays: what :func:`rollout_arrays` returns for its message."""
        if len(self.rewards) != len(self.actions) or not self.actions:
            raise RuntimeError("a rollout needs at least one step, each with its rewards")
        optional = {}
        if self.sample_masks:
            optional["sample_mask"] = np.stack(self.sample_masks)
        if self.extra:
            if last_extra is None:
                raise RuntimeError("a rollout with odometry inputs needs the last frame's (last_extra)")
            optional["extra"] = np.stack([*self.extra, np.asarray(last_extra, dtype=np.float32)])
        return {
            "agent_ids": self.agent_ids.astype(np.int64),
            "obs": np.stack([*self.observations, np.asarray(last_observations, dtype=np.float32)]),
            "actions": np.stack(self.actions).astype(np.int64),
            "rewards": np.stack(self.rewards),
            "train_mask": np.stack(self.train_masks),
            "loss_mask": np.stack(self.loss_mask).astype(np.float32),
            "value_mask": np.stack(self.value_mask).astype(np.float32),
            **optional,
        }

    def to_message(self, last_observations: np.ndarray, food: float = 0.0, last_extra: np.ndarray | None = None):
        from formic_interfaces.msg import Rollout

        a = self.arrays(last_observations, last_extra)
        frames, agents, channels, size, _ = a["obs"].shape
        return Rollout(
            weights_version=self.weights_version, host=self.host, episode=self.episode,
            n_agents=agents, n_steps=frames - 1, channels=channels, size=size,
            agent_ids=_typed("I", self.agent_ids, np.uint32),
            observations=_typed("f", a["obs"], np.float32),
            actions=a["actions"].astype(np.uint8).tobytes(),
            rewards=_typed("f", a["rewards"], np.float32),
            valid_masks=a["train_mask"].astype(np.uint8).tobytes(),
            loss_mask=a["loss_mask"].astype(np.uint8).tobytes(),
            value_mask=a["value_mask"].astype(np.uint8).tobytes(),
            sample_masks=a["sample_mask"].astype(np.uint8).tobytes() if "sample_mask" in a else b"",
            extra_inputs=_typed("f", a["extra"], np.float32) if "extra" in a else _typed("f", np.zeros(0), np.float32),
            food=float(food),
        )


def _typed(typecode: str, values: np.ndarray, dtype):
    import array

    out = array.array(typecode)
    out.frombytes(np.ascontiguousarray(values, dtype=dtype).tobytes())
    return out


def rollout_arrays(msg) -> dict[str, np.ndarray]:
    """A received Rollout as arrays (T+1 observation frames, T of everything else)."""
    steps, agents, channels, size = int(msg.n_steps), int(msg.n_agents), int(msg.channels), int(msg.size)

    def field(name: str, dtype, shape: tuple[int, ...]) -> np.ndarray:
        values = np.frombuffer(getattr(msg, name), dtype=dtype)
        if values.size != int(np.prod(shape)):
            raise ValueError(f"Rollout.{name} has {values.size} values, expected {int(np.prod(shape))} {shape}")
        return values.reshape(shape)

    if steps < 1 or agents < 1:
        raise ValueError(f"empty rollout ({steps} steps, {agents} agents)")
    optional = {}
    if len(msg.sample_masks):
        optional["sample_mask"] = field("sample_masks", np.uint8, (steps, agents, N_ACTIONS)).astype(bool)
    if len(msg.extra_inputs):
        optional["extra"] = field("extra_inputs", np.float32, (steps + 1, agents, N_EXTRA_INPUTS))
    return {
        "agent_ids": field("agent_ids", np.uint32, (agents,)).astype(np.int64),
        "obs": field("observations", np.float32, (steps + 1, agents, channels, size, size)),
        "actions": field("actions", np.uint8, (steps, agents)).astype(np.int64),
        "rewards": field("rewards", np.float32, (steps, agents)),
        "train_mask": field("valid_masks", np.uint8, (steps, agents, N_ACTIONS)).astype(bool),
        "loss_mask": field("loss_mask", np.uint8, (steps, agents)).astype(np.float32),
        "value_mask": field("value_mask", np.uint8, (steps, agents)).astype(np.float32),
        **optional,
    }


def apply_weights(policy, msg) -> int:
    """Load a Weights message into a learned policy (``weights_only`` loading); returns its
    version. Hosts call this between episodes."""
    payload = read_checkpoint(bytes(msg.data))
    config = NetworkConfig.from_dict(payload["network"])
    if config != policy.net.config:
        raise CheckpointError(f"weights for network {config} do not fit the policy's {policy.net.config}")
    policy.load_state_dict(payload["state_dict"])
    return int(msg.version)


def train_config_from_dict(data: dict) -> TrainConfig:
    """A TrainConfig from its JSON form (a run directory's ``config.json``): lists become
    the tuples the fields hold, so the config equals the one that was written."""
    known = {f.name for f in dataclasses.fields(TrainConfig)}
    unknown = sorted(set(data) - known)
    if unknown:
        raise ValueError(f"unknown training settings: {', '.join(unknown)}")

    def tuples(value):
        return tuple(tuples(v) for v in value) if isinstance(value, list) else value

    return TrainConfig(**{key: tuples(value) for key, value in data.items()})


def load_train_config(path: str | Path) -> TrainConfig:
    return train_config_from_dict(json.loads(Path(path).read_text()))


def training_network(cfg: TrainConfig) -> ForMICNet:
    """The network as the in-process trainer builds it (channels-last memory format: the same
    format gives the same arithmetic, so a host acts bit for bit as the trainer would)."""
    config = dataclasses.replace(NETWORK_PRESETS[cfg.network], view_size=cfg.view_size)
    return ForMICNet(config).to(memory_format=torch.channels_last)


def sampling_seed(cfg: TrainConfig, weights_version: int, first_agent: int) -> int:
    """Seed of a learning host's torch sampler. The in-process trainer seeds its sampler with
    ``seed`` (``seed + updates`` when it resumes); a host driving the whole team (ids from 0)
    does the same with the weights version it starts from, so it draws the very same actions.
    Hosts whose agents start elsewhere get streams of their own."""
    return cfg.seed + int(weights_version) + SAMPLER_STRIDE * int(first_agent)


def trainer_stream(cfg: TrainConfig, weights_version: int) -> np.random.Generator:
    """The in-process trainer's numpy stream (``Trainer.rng``) at ``weights_version`` updates:
    ``[seed, 5]`` fresh, ``[seed, 5, updates]`` resumed. It draws, in this order, each
    episode's filter-annealing choice (:meth:`Learner.episode_draws`), the "replace" filter's
    replacements while acting, and each update's minibatch permutations (one per epoch)."""
    key = [cfg.seed, 5] if weights_version == 0 else [cfg.seed, 5, int(weights_version)]
    return np.random.default_rng(key)


def unfiltered_agents(cfg: TrainConfig, stream: np.random.Generator, episode: int) -> np.ndarray:
    """The episode-start draw of the in-process trainer: which agents (of the whole team, by
    id) act without the training filter in global episode ``episode``."""
    return stream.random(sum(cfg.teams)) >= filter_probability(cfg, episode)


def allowed_actions(cfg: TrainConfig, train_mask: np.ndarray, unfiltered: np.ndarray) -> np.ndarray:
    """What the behaviour policy may sample ("mask" mode): the training filter's sampling mask
    (..., A, 5), everything for the agents (rows A) that act unfiltered this episode."""
    allowed = sampling_mask(cfg, train_mask)
    allowed[..., unfiltered, :] = True
    return allowed


class LearningActor:
    """A host's agents while training, as :class:`formic_trainer.train.Trainer` runs them: its
    network, one LSTM state per agent, its torch sampler (:func:`select_actions` under the
    training filter, one generator over the host's agents in id order) and, for the learning
    agents among them (``cfg.learning_agents``), a :class:`RolloutCollector` per chunk of
    ``cfg.rollout_steps`` steps.

    The in-process trainer's numpy stream decides each episode's unfiltered agents (filter
    annealing) and the "replace" filter's replacements, and its update draws from it too. The
    host keeps a mirror (:func:`trainer_stream`): it draws what the trainer draws while acting
    and replays each update's permutations after sending the rollout, so host and trainer
    node agree on every draw, exactly as in one process, when one host drives the whole team.

    Per episode: :meth:`start_episode`; per step :meth:`act`, then :meth:`outcome` with what
    the next observations carry, which returns the chunk's Rollout message when the chunk is
    complete (``rollout_steps`` steps, or the episode's end). ``first_episode``: the global
    episode number of the first episode (a resumed run's)."""

    def __init__(self, cfg: TrainConfig, agent_ids, host: str = "", first_episode: int = 0):
        self.cfg, self.host = cfg, host
        self.ids = np.asarray(sorted(agent_ids), dtype=np.int64)
        self.net = training_network(cfg)
        self.learning = (np.arange(len(self.ids)) if cfg.learning_agents < 0
                         else np.flatnonzero(self.ids < cfg.learning_agents))
        self.generator = torch.Generator()
        self.stream: np.random.Generator | None = None  # seeded with the first weights
        self.version = -1  # weights version loaded (-1: none yet)
        self.episode = first_episode - 1  # global episode number
        self.unfiltered: np.ndarray | None = None  # this episode's draw, at its first action
        self.state = self.net.initial_state(len(self.ids))
        self.collector: RolloutCollector | None = None
        self.food = 0.0
        self.loads = np.zeros(len(self.ids))

    def load_state_dict(self, state_dict: dict) -> None:
        self.net.load_state_dict(state_dict)

    def load_weights(self, msg) -> int:
        """Switch to a Weights message; the first one also seeds the samplers."""
        first = self.version < 0
        self.version = apply_weights(self, msg)
        if first:
            self.generator.manual_seed(sampling_seed(self.cfg, self.version, int(self.ids[0])))
            self.stream = trainer_stream(self.cfg, self.version)
        if self.collector is not None and not len(self.collector):
            self.collector.weights_version = self.version
        return self.version

    def start_episode(self, loads: np.ndarray) -> None:
        self.episode += 1
        self.unfiltered = None
        self.state = self.net.initial_state(len(self.ids))
        self._new_chunk(loads)

    def _new_chunk(self, loads: np.ndarray) -> None:
        self.collector = RolloutCollector(self.ids[self.learning], self.host, self.episode, self.version)
        self.food = 0.0
        self.loads = np.asarray(loads, dtype=np.float64)

    @torch.no_grad()
    def act(self, batch: AgentBatch, train_mask: np.ndarray) -> np.ndarray:
        """Actions for every agent of the batch (rows in id order, the host's agents); needs
        weights (:meth:`load_weights`)."""
        if self.unfiltered is None:
            self.unfiltered = unfiltered_agents(self.cfg, self.stream, self.episode)[self.ids]
        obs = torch.from_numpy(np.ascontiguousarray(batch.observations))[None]
        extra = nest_features(batch.positions, batch.loads, batch.world_shape)
        logits, _, self.state = self.net(obs, self.state, torch.from_numpy(extra)[None])
        allowed = allowed_actions(self.cfg, train_mask, self.unfiltered)
        actions, _, value_mask = select_actions(self.cfg, logits[0], batch.action_mask, train_mask, self.generator,
                                                self.stream, sample_mask=allowed)
        rows = self.learning
        self.collector.add_step(batch.observations[rows], train_mask[rows], batch.queued[rows], actions[rows],
                                value_mask[rows], sample_mask=allowed[rows],
                                extra=extra[rows] if self.net.config.nest_input else None)
        return actions

    def outcome(self, batch: AgentBatch, team_rewards: np.ndarray, rows: np.ndarray, done: bool):
        """The observations after a step (``team_rewards``: every agent's; ``rows``: this
        host's); returns the Rollout message when the chunk is complete, else None."""
        rewards = share_rewards(team_rewards, self.cfg.team_reward)[rows]
        self.collector.add_rewards(rewards[self.learning])
        loads = np.asarray(batch.loads, dtype=np.float64)
        self.food += float(np.clip(self.loads - loads, 0.0, None).sum())  # every agent's deliveries
        self.loads = loads
        if not done and len(self.collector) < self.cfg.rollout_steps:
            return None
        if not len(self.learning):  # none of these agents learns: nothing to send
            self._new_chunk(loads)
            return None
        last_extra = (nest_features(batch.positions, batch.loads, batch.world_shape)[self.learning]
                      if self.net.config.nest_input else None)
        msg = self.collector.to_message(batch.observations[self.learning], food=self.food, last_extra=last_extra)
        for _ in range(self.cfg.epochs):  # the trainer's update of this chunk draws these
            self.stream.permutation(len(self.learning))
        self._new_chunk(loads)
        return msg


# ----------------------------------------------------------------------------- learning
def scale_rewards(rewards: np.ndarray, scale: float) -> np.ndarray:
    """The trainer's reward scaling, in float64 like the in-process trainer."""
    return (rewards.astype(np.float64) * scale).astype(np.float32)


@torch.no_grad()
def behaviour_batch(net: ForMICNet, cfg: TrainConfig, arrays: dict[str, np.ndarray],
                    state: tuple[torch.Tensor, torch.Tensor] | None = None):
    """The batch :func:`update` takes, from a rollout and the network that chose its actions:
    log-probabilities, values and the bootstrap value are recomputed one step at a time (as the
    host ran it). Returns (data, LSTM state after the rollout's last step)."""
    steps, agents = arrays["actions"].shape
    sample_mask = arrays.get("sample_mask")
    if sample_mask is None:
        sample_mask = sampling_mask(cfg, arrays["train_mask"])
    obs = torch.from_numpy(np.ascontiguousarray(arrays["obs"]))
    actions = torch.from_numpy(arrays["actions"])
    if net.config.nest_input and "extra" not in arrays:
        raise ValueError("this network takes odometry inputs and the rollout carries none (Rollout.extra_inputs)")
    extra_frames = arrays.get("extra", np.zeros((steps + 1, agents, N_EXTRA_INPUTS), np.float32))
    extra = torch.from_numpy(np.ascontiguousarray(extra_frames))
    h, c = state if state is not None else net.initial_state(agents)
    h0, c0 = h.numpy().copy(), c.numpy().copy()
    logp = np.zeros((steps, agents), np.float32)
    values = np.zeros((steps, agents), np.float32)
    for t in range(steps):
        logits, value, (h, c) = net(obs[t][None], (h, c), extra[t][None])
        logits = logits[0]
        if cfg.action_filter == "mask":
            logits = logits.masked_fill(~torch.from_numpy(sample_mask[t]), -1e9)
        logp[t] = torch.log_softmax(logits, -1).gather(-1, actions[t][:, None])[:, 0].numpy()
        values[t] = value[0].numpy()
    _, next_value, _ = net(obs[steps][None], (h, c), extra[steps][None])
    data = {
        "obs": arrays["obs"][:steps],
        "extra": extra_frames[:steps],
        "actions": arrays["actions"],
        "logp": logp,
        "values": values,
        "rewards": scale_rewards(arrays["rewards"], cfg.reward_scale),
        "train_mask": arrays["train_mask"],
        "sample_mask": sample_mask,
        "loss_mask": arrays["loss_mask"],
        "value_mask": arrays["value_mask"],
        "h0": h0,
        "c0": c0,
        "next_value": next_value[0].numpy(),
    }
    return data, (h, c)


class Learner:
    """The in-process trainer's state, fed rollouts instead of its own worlds."""

    def __init__(self, cfg: TrainConfig, run_dir: Path, resume: bool = True, max_lag: int = DEFAULT_MAX_LAG,
                 log: Callable[[str], None] = print):
        if cfg.imitate:
            raise ValueError("imitation runs its demonstrator beside the training worlds; train it in-process "
                             "(formic train)")
        self.trainer = Trainer(cfg, run_dir, resume=resume, log=log)
        self.cfg, self.max_lag, self.log = cfg, max_lag, log
        self.behaviour = copy.deepcopy(self.trainer.net)  # same memory format: same arithmetic
        self.versions: OrderedDict[int, dict[str, torch.Tensor]] = OrderedDict()
        self.lstm: dict[str, tuple[int, tuple[torch.Tensor, torch.Tensor]]] = {}  # host -> (episode, state)
        self.episode_food: dict[str, tuple[int, int, float]] = {}  # host -> (episode, steps, food so far)
        self.unfiltered: dict[str, np.ndarray] = {}  # host -> its episode's unfiltered agents (team ids)
        self.dropped = 0
        self._remember_version()

    @property
    def version(self) -> int:
        return self.trainer.updates

    def _remember_version(self) -> None:
        self.versions[self.version] = {k: v.detach().clone() for k, v in self.trainer.net.state_dict().items()}
        while len(self.versions) > self.max_lag + 1:
            self.versions.popitem(last=False)

    def learn(self, arrays: dict[str, np.ndarray], weights_version: int, host: str = "",
              episode: int = 0, food: float = 0.0) -> dict | None:
        """One update from one rollout; None (and counted as dropped) when the weights that
        chose its actions are no longer kept."""
        behaviour = self.versions.get(weights_version)
        if behaviour is None:
            self.dropped += 1
            self.log(f"dropped a rollout from {host or '?'}: weights version {weights_version}, "
                     f"now {self.version} (keeping {self.max_lag} older versions)")
            return None
        self.behaviour.load_state_dict(behaviour)
        previous = self.lstm.get(host)
        new_episode = previous is None or previous[0] != episode
        state = None if new_episode else previous[1]
        if state is not None and state[0].shape[1] != arrays["actions"].shape[1]:
            state = None
        drawn = self.episode_draws(host, new_episode, arrays)  # keeps the trainer's stream in step
        arrays = {"sample_mask": drawn, **arrays}  # the host's own masks, when it sent them, win
        data, final_state = behaviour_batch(self.behaviour, self.cfg, arrays, state)
        self.lstm[host] = (episode, final_state)
        trainer = self.trainer
        set_learning_rate(trainer.optimizer, self.cfg, trainer.updates)
        stats = update(trainer.net, trainer.optimizer, self.cfg, data, trainer.rng)
        trainer.updates += 1
        trainer.env_steps += int(arrays["actions"].size)
        self._remember_version()
        stats["lag"] = float(self.version - 1 - weights_version)
        stats["rollout_food"] = float(food)
        for key, value in stats.items():
            trainer.writer.add_scalar(f"ros/{key}", value, trainer.updates)
        same = self.episode_food.get(host, (-1, 0, 0.0))
        steps, total = (same[1], same[2]) if same[0] == episode else (0, 0.0)
        steps, total = steps + arrays["actions"].shape[0], total + float(food)
        self.episode_food[host] = (episode, steps, total)
        if steps >= self.cfg.episode_steps:  # the learning curve and checkpoints, as `formic train` has them
            stats["episode_food"] = total
            trainer.writer.add_scalar("train/food_mean", total, trainer.episode)
            if trainer.episode % self.cfg.checkpoint_every == 0:
                trainer.save()
        return stats

    def episode_draws(self, host: str, new_episode: bool, arrays: dict[str, np.ndarray]) -> np.ndarray:
        """What the in-process trainer draws from its stream between two updates, drawn here
        in the same order, so the update's permutations match it and the hosts' mirrors
        (:class:`LearningActor`): at an episode's first chunk, which agents act unfiltered
        (counting the episode); then the "replace" filter's replacements, replayed from the
        rollout (complete when every agent learns). Returns the chunk's sampling masks."""
        trainer = self.trainer
        if new_episode:
            self.unfiltered[host] = unfiltered_agents(self.cfg, trainer.rng, trainer.episode)
            trainer.episode += 1
        if self.cfg.action_filter == "replace":
            for t, i in zip(*np.nonzero(arrays["value_mask"] == 0)):  # step by step, agents in order
                trainer.rng.choice(np.flatnonzero(arrays["train_mask"][t, i]))
        team = self.unfiltered.get(host, np.zeros(0, dtype=bool))
        ids = arrays.get("agent_ids", np.arange(arrays["actions"].shape[1]))
        unfiltered = np.zeros(len(ids), dtype=bool)
        inside = ids < len(team)
        unfiltered[inside] = team[ids[inside]]
        return allowed_actions(self.cfg, arrays["train_mask"], unfiltered)

    def weights_payload(self) -> tuple[bytes, str]:
        """The current weights as Weights.data bytes and their content id."""
        data = state_dict_bytes(self.trainer.net)
        return data, hashlib.sha256(data).hexdigest()[:12]

    def close(self) -> None:
        self.trainer.save()
        self.trainer.writer.close()


# ----------------------------------------------------------------------------- the node
def serve_trainer(cfg: TrainConfig, run_dir: Path, resume: bool = True, namespace: str = "/formic",
                  domain_id: int | None = None, max_updates: int | None = None, max_rollouts: int | None = None,
                  max_lag: int = DEFAULT_MAX_LAG, log: Callable[[str], None] = print) -> dict:
    """Run node ``trainer`` until SIGINT/SIGTERM, ``max_updates`` updates or ``max_rollouts``
    rollouts received (learned or dropped: what a launcher knows its hosts send). The
    checkpoint is saved on every exit but a SIGKILL (and every ``cfg.checkpoint_every``
    episodes, atomically)."""
    from formic_interfaces.msg import Rollout, Weights
    from rclpy.duration import Duration
    from rclpy.node import Node
    from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy

    from .env import ros_session
    from .qos import LATCHED

    learner = Learner(cfg, run_dir, resume=resume, max_lag=max_lag, log=log)
    rollout_qos = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=ROLLOUT_DEPTH,
                             reliability=ReliabilityPolicy.RELIABLE, durability=DurabilityPolicy.VOLATILE)
    pending: deque = deque()
    stop: list[bool] = []
    updates_here = rollouts_here = 0
    started = time.monotonic()
    try:
        with ros_session(domain_id) as executor:
            handlers = {s: signal.signal(s, lambda *_: stop.append(True)) for s in (signal.SIGINT, signal.SIGTERM)}
            try:
                node = Node("trainer", namespace=namespace)
                executor.add_node(node)
                publisher = node.create_publisher(Weights, WEIGHTS, LATCHED)
                node.create_subscription(Rollout, ROLLOUTS, lambda msg: pending.append(msg), rollout_qos)
                model_json = json.dumps(learner.trainer.net.config.to_dict())

                def broadcast() -> None:
                    data, content_id = learner.weights_payload()
                    publisher.publish(Weights(version=learner.version, model_config_json=model_json,
                                              checkpoint_id=content_id, data=data))

                broadcast()
                log(f"trainer: weights version {learner.version} published; waiting for rollouts")
                while not (stop or (max_updates is not None and updates_here >= max_updates)
                           or (max_rollouts is not None and rollouts_here >= max_rollouts)):
                    executor.spin_once(timeout_sec=0.0 if pending else 0.1)
                    if not pending:
                        continue
                    msg = pending.popleft()
                    rollouts_here += 1
                    try:
                        arrays = rollout_arrays(msg)
                    except ValueError as exc:
                        learner.dropped += 1
                        log(f"dropped a malformed rollout from {msg.host or '?'}: {exc}")
                        continue
                    stats = learner.learn(arrays, msg.weights_version, msg.host, msg.episode, msg.food)
                    if stats is None:
                        continue
                    updates_here += 1
                    broadcast()
                    log(f"update {learner.version}: {msg.n_steps}x{msg.n_agents} from {msg.host or '?'} "
                        f"(episode {msg.episode}, lag {stats['lag']:.0f}, food {msg.food:.1f}) "
                        f"loss {stats['loss']:.3f}"
                        + (f"; episode food {stats['episode_food']:.1f}" if "episode_food" in stats else ""))
                if not stop:  # the last weights reach the hosts before the node goes
                    publisher.wait_for_all_acked(Duration(seconds=2.0))
            finally:
                for sig, handler in handlers.items():
                    signal.signal(sig, handler)
    finally:
        learner.close()
    return {"run_dir": str(run_dir), "version": learner.version, "updates": updates_here,
            "dropped": learner.dropped, "seconds": time.monotonic() - started}
