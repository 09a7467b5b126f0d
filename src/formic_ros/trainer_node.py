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
episode sent in several chunks continues its LSTM state from the previous chunk. Networks
with odometry inputs (``nest_input``) cannot train here: a Rollout carries no positions.
"""

from __future__ import annotations

import copy
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
from formic_agent.network import N_ACTIONS, N_EXTRA_INPUTS, ForMICNet, NetworkConfig
from formic_trainer.train import TrainConfig, Trainer, update

ROLLOUTS = "rollouts"
WEIGHTS = "weights"
ROLLOUT_DEPTH = 16
DEFAULT_MAX_LAG = 4  # weights versions a rollout may lag behind and still be learned from


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

    def __len__(self) -> int:
        return len(self.actions)

    def add_step(self, observations: np.ndarray, train_masks: np.ndarray, queued: np.ndarray,
                 actions: np.ndarray, value_mask: np.ndarray | None = None) -> None:
        """One decision: observations (A, C, V, V), training masks (A, 5), queued (A,) (a
        queued agent's step is masked out of the losses), actions (A,), and value_mask (A,)
        (0 where the action filter replaced the sampled action)."""
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

    def arrays(self, last_observations: np.ndarray) -> dict[str, np.ndarray]:
        """The chunk as arrays: what :func:`rollout_arrays` returns for its message."""
        if len(self.rewards) != len(self.actions) or not self.actions:
            raise RuntimeError("a rollout needs at least one step, each with its rewards")
        return {
            "obs": np.stack([*self.observations, np.asarray(last_observations, dtype=np.float32)]),
            "actions": np.stack(self.actions).astype(np.int64),
            "rewards": np.stack(self.rewards),
            "train_mask": np.stack(self.train_masks),
            "loss_mask": np.stack(self.loss_mask).astype(np.float32),
            "value_mask": np.stack(self.value_mask).astype(np.float32),
        }

    def to_message(self, last_observations: np.ndarray, food: float = 0.0):
        from formic_interfaces.msg import Rollout

        a = self.arrays(last_observations)
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
    return {
        "obs": field("observations", np.float32, (steps + 1, agents, channels, size, size)),
        "actions": field("actions", np.uint8, (steps, agents)).astype(np.int64),
        "rewards": field("rewards", np.float32, (steps, agents)),
        "train_mask": field("valid_masks", np.uint8, (steps, agents, N_ACTIONS)).astype(bool),
        "loss_mask": field("loss_mask", np.uint8, (steps, agents)).astype(np.float32),
        "value_mask": field("value_mask", np.uint8, (steps, agents)).astype(np.float32),
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
    obs = torch.from_numpy(np.ascontiguousarray(arrays["obs"]))
    actions = torch.from_numpy(arrays["actions"])
    extra = torch.zeros(1, agents, N_EXTRA_INPUTS)
    h, c = state if state is not None else net.initial_state(agents)
    h0, c0 = h.numpy().copy(), c.numpy().copy()
    logp = np.zeros((steps, agents), np.float32)
    values = np.zeros((steps, agents), np.float32)
    for t in range(steps):
        logits, value, (h, c) = net(obs[t][None], (h, c), extra)
        logits = logits[0]
        if cfg.action_filter == "mask":
            logits = logits.masked_fill(~torch.from_numpy(arrays["train_mask"][t]), -1e9)
        logp[t] = torch.log_softmax(logits, -1).gather(-1, actions[t][:, None])[:, 0].numpy()
        values[t] = value[0].numpy()
    _, next_value, _ = net(obs[steps][None], (h, c), extra)
    data = {
        "obs": arrays["obs"][:steps],
        "extra": np.zeros((steps, agents, N_EXTRA_INPUTS), np.float32),
        "actions": arrays["actions"],
        "logp": logp,
        "values": values,
        "rewards": scale_rewards(arrays["rewards"], cfg.reward_scale),
        "train_mask": arrays["train_mask"],
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
        self.trainer = Trainer(cfg, run_dir, resume=resume, log=log)
        if self.trainer.net.config.nest_input:
            raise ValueError("networks with nest_input need odometry, which Rollout messages do not carry; "
                             "train them in-process (formic train)")
        self.cfg, self.max_lag, self.log = cfg, max_lag, log
        self.behaviour = copy.deepcopy(self.trainer.net)  # same memory format: same arithmetic
        self.versions: OrderedDict[int, dict[str, torch.Tensor]] = OrderedDict()
        self.lstm: dict[str, tuple[int, tuple[torch.Tensor, torch.Tensor]]] = {}  # host -> (episode, state)
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
        state = previous[1] if previous is not None and previous[0] == episode else None
        if state is not None and state[0].shape[1] != arrays["actions"].shape[1]:
            state = None
        data, final_state = behaviour_batch(self.behaviour, self.cfg, arrays, state)
        self.lstm[host] = (episode, final_state)
        trainer = self.trainer
        stats = update(trainer.net, trainer.optimizer, self.cfg, data, trainer.rng)
        trainer.updates += 1
        trainer.env_steps += int(arrays["actions"].size)
        if previous is None or previous[0] != episode:
            trainer.episode += 1
        self._remember_version()
        stats["lag"] = float(self.version - 1 - weights_version)
        stats["rollout_food"] = float(food)
        for key, value in stats.items():
            trainer.writer.add_scalar(f"ros/{key}", value, trainer.updates)
        if trainer.updates % self.cfg.checkpoint_every == 0:
            trainer.save()
        return stats

    def weights_payload(self) -> tuple[bytes, str]:
        """The current weights as Weights.data bytes and their content id."""
        data = state_dict_bytes(self.trainer.net)
        return data, hashlib.sha256(data).hexdigest()[:12]

    def close(self) -> None:
        self.trainer.save()
        self.trainer.writer.close()


# ----------------------------------------------------------------------------- the node
def serve_trainer(cfg: TrainConfig, run_dir: Path, resume: bool = True, namespace: str = "/formic",
                  domain_id: int | None = None, max_updates: int | None = None,
                  max_lag: int = DEFAULT_MAX_LAG, log: Callable[[str], None] = print) -> dict:
    """Run node ``trainer`` until SIGINT/SIGTERM (or ``max_updates``); the checkpoint is saved
    on every exit but a SIGKILL (and every ``cfg.checkpoint_every`` updates, atomically)."""
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
    updates_here = 0
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
                while not stop and (max_updates is None or updates_here < max_updates):
                    executor.spin_once(timeout_sec=0.0 if pending else 0.1)
                    if not pending:
                        continue
                    msg = pending.popleft()
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
                        f"loss {stats['loss']:.3f}")
                if max_updates is not None:  # the last weights reach the hosts before the node goes
                    publisher.wait_for_all_acked(Duration(seconds=2.0))
            finally:
                for sig, handler in handlers.items():
                    signal.signal(sig, handler)
    finally:
        learner.close()
    return {"run_dir": str(run_dir), "version": learner.version, "updates": updates_here,
            "dropped": learner.dropped, "seconds": time.monotonic() - started}
