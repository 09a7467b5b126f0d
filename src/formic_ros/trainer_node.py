"""The trainer node: Rollout messages in, :class:`formic_trainer.learner.Learner` updates
(``formic train``'s own) out as Weights versions (the updates so far; latched, so a late host
gets the newest), identified by a hash of their bytes.

A Rollout carries what the environment produced; the node recomputes what the network said
(log-probabilities, values, bootstrap value) with the weights version that acted, step by
step as the host did, so PPO's ratio is taken against the behaviour policy (versions are kept
for ``max_lag`` updates; older rollouts are dropped). An episode's chunks continue its LSTM
state. The hosts' side is :mod:`formic_ros.learning_host`.
"""

from __future__ import annotations

import contextlib
import copy
import hashlib
import time
from collections import OrderedDict, deque
from collections.abc import Callable
from pathlib import Path

import numpy as np
import torch

from formic_agent.checkpoint import CheckpointError, read_checkpoint, state_dict_bytes
from formic_agent.network import N_EXTRA_INPUTS, ForMICNet, NetworkConfig
from formic_trainer.algorithm import sampling_mask
from formic_trainer.config import TrainConfig
from formic_trainer.learner import Learner

from . import qos

DEFAULT_MAX_LAG = 4  # weights versions a rollout may lag behind and still be learned from


def apply_weights(policy, msg) -> int:
    """Load a Weights message into a learned policy (or anything with its ``net`` and
    ``load_state_dict``; ``weights_only`` loading); returns its version."""
    payload = read_checkpoint(bytes(msg.data))
    config = NetworkConfig.from_dict(payload["network"])
    if config != policy.net.config:
        raise CheckpointError(f"weights for network {config} do not fit the policy's {policy.net.config}")
    policy.load_state_dict(payload["state_dict"])
    return int(msg.version)


@torch.no_grad()
def behaviour_outputs(net: ForMICNet, cfg: TrainConfig, rollout: dict[str, np.ndarray],
                      state: tuple[torch.Tensor, torch.Tensor] | None = None):
    """What the actor's network said over a rollout, recomputed one step at a time as the
    host ran it (log-probabilities, values, bootstrap value, initial LSTM state; the sampling
    masks and extra inputs when the rollout lacks them). Returns (those arrays, the LSTM
    state after the rollout's last step)."""
    steps, agents = rollout["actions"].shape
    sample_mask = rollout.get("sample_mask")
    if sample_mask is None:
        sample_mask = sampling_mask(cfg, rollout["train_mask"])
    if net.config.reads_extra and "extra" not in rollout:
        raise ValueError("this network reads extra inputs and the rollout carries none (Rollout.extra_inputs)")
    extra_frames = rollout.get("extra", np.zeros((steps + 1, agents, N_EXTRA_INPUTS), np.float32))
    obs = torch.from_numpy(np.ascontiguousarray(rollout["obs"]))
    extra = torch.from_numpy(np.ascontiguousarray(extra_frames))
    actions = torch.from_numpy(rollout["actions"])
    h, c = state if state is not None else net.initial_state(agents)
    out = {"h0": h.numpy().copy(), "c0": c.numpy().copy(), "sample_mask": sample_mask, "extra": extra_frames,
           "logp": np.zeros((steps, agents), np.float32), "values": np.zeros((steps, agents), np.float32)}
    for t in range(steps):
        logits, value, (h, c) = net(obs[t][None], (h, c), extra[t][None])
        logits = logits[0]
        if cfg.action_filter == "mask":
            logits = logits.masked_fill(~torch.from_numpy(sample_mask[t]), -1e9)
        out["logp"][t] = torch.log_softmax(logits, -1).gather(-1, actions[t][:, None])[:, 0].numpy()
        out["values"][t] = value[0].numpy()
    _, next_value, _ = net(obs[steps][None], (h, c), extra[steps][None])
    out["next_value"] = next_value[0].numpy()
    return out, (h, c)


class RemoteLearner:
    """A :class:`Learner` fed Rollout messages from the hosts: it keeps the recent weights
    versions (the behaviour policies), each host's LSTM state across an episode's chunks, and
    ends an episode (learning curve, checkpoint) when its steps are all in."""

    def __init__(self, cfg: TrainConfig, run_dir: Path, resume: bool = True, max_lag: int = DEFAULT_MAX_LAG,
                 log: Callable[[str], None] = print):
        if cfg.imitate:
            raise ValueError("imitation runs its demonstrator beside the training worlds; train it in-process "
                             "(formic train)")
        self.learner = Learner(cfg, run_dir, resume=resume, log=log)
        self.cfg, self.max_lag, self.log = cfg, max_lag, log
        self.behaviour = copy.deepcopy(self.learner.net)  # same memory format: same arithmetic
        self.versions: OrderedDict[int, dict[str, torch.Tensor]] = OrderedDict()
        self.hosts: dict[str, tuple] = {}  # host -> (its episode, LSTM state, steps and food so far)
        self.ended = -1  # the newest episode ended
        self.dropped = 0
        self._remember_version()

    @property
    def version(self) -> int:
        return self.learner.version

    def _remember_version(self) -> None:
        self.versions[self.version] = {k: v.detach().clone() for k, v in self.learner.net.state_dict().items()}
        while len(self.versions) > self.max_lag + 1:
            self.versions.popitem(last=False)

    def learn(self, rollout: dict[str, np.ndarray], weights_version: int, host: str = "",
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
        same, state, steps, total = self.hosts.get(host, (episode, None, 0, 0.0))
        if same != episode:  # the host's next episode: its LSTM state starts afresh
            state, steps, total = None, 0, 0.0
        if state is not None and state[0].shape[1] != rollout["actions"].shape[1]:
            state = None
        outputs, final_state = behaviour_outputs(self.behaviour, self.cfg, rollout, state)
        steps, total = steps + rollout["actions"].shape[0], total + float(food)
        self.hosts[host] = (episode, final_state, steps, total)
        stats = self.learner.learn({**rollout, **outputs})
        self._remember_version()
        stats["lag"] = float(self.version - 1 - weights_version)
        stats["rollout_food"] = float(food)
        self.learner.record("ros", stats, self.version)
        if steps >= self.cfg.episode_steps and episode > self.ended:  # as `formic train` ends its episodes
            self.ended = episode
            stats["episode_food"] = total
            self.learner.end_episodes(1, {"food_mean": total})
        return stats

    def weights_payload(self) -> tuple[bytes, str]:
        """The current weights as Weights.data bytes and their content id."""
        data = state_dict_bytes(self.learner.net)
        return data, hashlib.sha256(data).hexdigest()[:12]

    def close(self) -> None:
        self.learner.close()


def serve_trainer(cfg: TrainConfig, run_dir: Path, resume: bool = True, namespace: str = qos.DEFAULT_NAMESPACE,
                  domain_id: int | None = None, max_updates: int | None = None, max_rollouts: int | None = None,
                  max_lag: int = DEFAULT_MAX_LAG, log: Callable[[str], None] = print) -> dict:
    """Run node ``trainer`` until SIGINT/SIGTERM, ``max_updates`` updates or ``max_rollouts``
    rollouts received (learned or dropped: what a launcher knows its hosts send). The
    checkpoint is saved on every exit but a SIGKILL (and every ``cfg.checkpoint_every``
    episodes, atomically)."""
    from formic_interfaces.msg import Rollout, Weights
    from rclpy.duration import Duration
    from rclpy.node import Node

    from .convert import WeightsPayload, decode_rollout, encode_weights
    from .env import ros_session, stop_requests

    learner = RemoteLearner(cfg, run_dir, resume=resume, max_lag=max_lag, log=log)
    pending: deque = deque()
    updates_here = rollouts_here = 0
    started = time.monotonic()
    with stop_requests() as stop, contextlib.closing(learner):  # the checkpoint is saved whatever comes
        with ros_session(domain_id, interrupt=False) as executor:
            node = Node("trainer", namespace=namespace)
            executor.add_node(node)
            publisher = node.create_publisher(Weights, qos.WEIGHTS, qos.LATCHED)
            node.create_subscription(Rollout, qos.ROLLOUTS, lambda msg: pending.append(msg), qos.ROLLOUT)
            model_config = learner.learner.net.config.to_dict()

            def broadcast() -> None:
                data, content_id = learner.weights_payload()
                publisher.publish(encode_weights(WeightsPayload(learner.version, data, content_id, model_config)))

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
                    arrays = decode_rollout(msg)
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
    return {"run_dir": str(run_dir), "version": learner.version, "updates": updates_here,
            "dropped": learner.dropped, "seconds": time.monotonic() - started}
