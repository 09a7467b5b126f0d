"""The learning half of the codec (:mod:`formic_ros.convert`): rollouts as
:class:`formic_trainer.rollout.Rollout` (field for field) and weights as a :class:`WeightsPayload`,
the two messages distributed training sends between learning hosts and the trainer."""

from __future__ import annotations

import json
from typing import NamedTuple

import numpy as np
from formic_interfaces.msg import Rollout as RolloutMsg
from formic_interfaces.msg import Weights

from formic_topics import EXTRA_INPUT_COUNT
from formic_trainer.rollout import Rollout
from formic_world.geometry import N_ACTIONS

from .wire import decode_encoded, f32, observation_fields, read, u8, u32


def encode_rollout(rollout: Rollout, encoding: str = "compact") -> RolloutMsg:
    """A :class:`Rollout` as the message, field for field (masks as 0/1 bytes; no imitation:
    empty), the observations in ``encoding``: compact (lossless) by default, as the world sends
    them, which cuts a rollout of 16 agents over 128 steps from 8.1 MB to 0.55 MB, few enough
    datagrams to cross a lossy link (docs/ros.md)."""
    frames, agents, channels, size, _ = rollout.observations.shape
    imitation = rollout.expert_actions is not None
    return RolloutMsg(
        n_agents=agents, n_steps=frames - 1, channels=channels, size=size,
        weights_version=rollout.weights_version, episode=rollout.episode, done=rollout.done, food=rollout.food,
        agent_ids=u32(rollout.agent_ids), **observation_fields(rollout.observations, encoding, "observations"),
        extra_inputs=f32(rollout.extra_inputs), actions=u8(rollout.actions), logprobs=f32(rollout.logprobs),
        values=f32(rollout.values), next_value=f32(rollout.next_value), h0=f32(rollout.h0), c0=f32(rollout.c0),
        rewards=f32(rollout.rewards), train_mask=u8(rollout.train_mask), sample_mask=u8(rollout.sample_mask),
        loss_mask=u8(rollout.loss_mask), value_mask=u8(rollout.value_mask),
        expert_actions=u8(rollout.expert_actions) if imitation else b"",
        imitation_mask=u8(rollout.imitation_mask) if imitation else b"",
    )


def decode_rollout(msg: RolloutMsg) -> Rollout:
    """Inverse of :func:`encode_rollout`, every array's size checked (ValueError)."""
    steps, agents, channels, size = int(msg.n_steps), int(msg.n_agents), int(msg.channels), int(msg.size)
    if steps < 1 or agents < 1:
        raise ValueError(f"empty rollout ({steps} steps, {agents} agents)")

    def field(name: str, dtype, *shape: int) -> np.ndarray:
        values = read(getattr(msg, name), dtype)
        if values.size != int(np.prod(shape)):
            raise ValueError(f"Rollout.{name} has {values.size} values, expected {int(np.prod(shape))} {shape}")
        return values.reshape(shape)

    rnn = max(len(msg.h0) // agents, 1)  # an empty LSTM state is malformed too
    imitation = len(msg.expert_actions) > 0
    return Rollout(
        weights_version=int(msg.weights_version), episode=int(msg.episode), done=bool(msg.done), food=float(msg.food),
        agent_ids=field("agent_ids", np.uint32, agents).astype(np.int64),
        observations=decode_encoded(msg, msg.observations, (steps + 1, agents, channels, size, size)),
        extra_inputs=field("extra_inputs", np.float32, steps + 1, agents, EXTRA_INPUT_COUNT),
        actions=field("actions", np.uint8, steps, agents).astype(np.int64),
        logprobs=field("logprobs", np.float32, steps, agents),
        values=field("values", np.float32, steps, agents),
        next_value=field("next_value", np.float32, agents),
        h0=field("h0", np.float32, 1, agents, rnn),
        c0=field("c0", np.float32, 1, agents, rnn),
        rewards=field("rewards", np.float32, steps, agents),
        train_mask=field("train_mask", np.uint8, steps, agents, N_ACTIONS).astype(bool),
        sample_mask=field("sample_mask", np.uint8, steps, agents, N_ACTIONS).astype(bool),
        loss_mask=field("loss_mask", np.uint8, steps, agents).astype(bool),
        value_mask=field("value_mask", np.uint8, steps, agents).astype(bool),
        expert_actions=field("expert_actions", np.uint8, steps, agents).astype(np.int64) if imitation else None,
        imitation_mask=field("imitation_mask", np.uint8, steps, agents).astype(bool) if imitation else None,
    )


class WeightsPayload(NamedTuple):
    version: int
    data: bytes  # formic_agent.checkpoint.state_dict_bytes (read with read_checkpoint)
    checkpoint_id: str
    model_config: dict


def encode_weights(weights: WeightsPayload) -> Weights:
    return Weights(version=weights.version, model_config_json=json.dumps(weights.model_config),
                   checkpoint_id=weights.checkpoint_id, data=weights.data)


def decode_weights(msg: Weights) -> WeightsPayload:
    return WeightsPayload(int(msg.version), bytes(msg.data), msg.checkpoint_id, json.loads(msg.model_config_json))


