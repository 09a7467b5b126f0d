"""Distributed training's messages: rollouts (hosts -> trainer) and weights (trainer -> hosts).

A Rollout carries what an actor's learning agents lived through in one chunk (observations,
actions, rewards, masks, the sampling masks they acted under and, for networks with the
odometry input, those inputs), not what the network said: the trainer node recomputes that
with the weights version that acted (``weights_version``).
"""

from __future__ import annotations

import array

import numpy as np

from formic_agent.checkpoint import CheckpointError, read_checkpoint
from formic_agent.network import N_ACTIONS, N_EXTRA_INPUTS, NetworkConfig

ROLLOUTS = "rollouts"
WEIGHTS = "weights"
ROLLOUT_DEPTH = 16


def _typed(typecode: str, values: np.ndarray, dtype):
    out = array.array(typecode)
    out.frombytes(np.ascontiguousarray(values, dtype=dtype).tobytes())
    return out


def rollout_message(rollout: dict[str, np.ndarray], host: str = "", episode: int = 0, weights_version: int = 0,
                    food: float = 0.0, extra: bool = True):
    """An actor's rollout (:meth:`formic_trainer.actor.Actor.rollout`) as a Rollout message;
    the odometry inputs only with ``extra`` (networks that read them)."""
    from formic_interfaces.msg import Rollout

    frames, agents, channels, size, _ = rollout["obs"].shape
    empty = _typed("f", np.zeros(0), np.float32)
    return Rollout(
        weights_version=int(weights_version), host=host, episode=int(episode),
        n_agents=agents, n_steps=frames - 1, channels=channels, size=size,
        agent_ids=_typed("I", rollout["agent_ids"], np.uint32),
        observations=_typed("f", rollout["obs"], np.float32),
        actions=rollout["actions"].astype(np.uint8).tobytes(),
        rewards=_typed("f", rollout["rewards"], np.float32),
        valid_masks=rollout["train_mask"].astype(np.uint8).tobytes(),
        loss_mask=rollout["loss_mask"].astype(np.uint8).tobytes(),
        value_mask=rollout["value_mask"].astype(np.uint8).tobytes(),
        sample_masks=rollout["sample_mask"].astype(np.uint8).tobytes() if "sample_mask" in rollout else b"",
        extra_inputs=_typed("f", rollout["extra"], np.float32) if extra and "extra" in rollout else empty,
        food=float(food),
    )


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
