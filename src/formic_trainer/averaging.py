"""The mean of one run's checkpoints (stochastic weight averaging, offline).

A policy trained with every team size at once swings from one checkpoint to the next (the
128-agent food most); the mean of the last few checkpoints of one run, whose weights lie in
one basin, is steadier than any one of them. ``scripts/average_checkpoints.py`` and the
recipes (:mod:`formic_trainer.recipes.run`) write it."""

from __future__ import annotations

import os
from pathlib import Path

import torch

from formic_agent.checkpoint import CheckpointError, checkpoint_id, load_network, read_checkpoint, save_checkpoint
from formic_agent.network import ForMICNet


def average_networks(paths: list[str | os.PathLike]) -> ForMICNet:
    """The network whose every tensor is the mean of the checkpoints' (same configuration)."""
    nets = [load_network(path)[0] for path in paths]
    config = nets[0].config
    for path, net in zip(paths, nets):
        if net.config != config:
            raise CheckpointError(f"{path}: network {net.config} differs from {paths[0]}'s {config}")
    states = [net.state_dict() for net in nets]
    averaged = {key: torch.stack([state[key] for state in states]).mean(dim=0) for key in states[0]}
    nets[0].load_state_dict(averaged)
    return nets[0]


def average_sources(paths: list[str | os.PathLike]) -> list[str]:
    """How a mean names its inputs (``averaged_from``): file name and content hash."""
    return [f"{Path(p).name} {checkpoint_id(p)}" for p in paths]


def averaged_from(mean: str | os.PathLike, paths: list[str | os.PathLike]) -> bool:
    """Whether the mean at ``mean`` names exactly ``paths`` (by file name, in order), each of
    them still there with the content it was averaged from. A snapshot no longer kept is taken
    on the mean's word: a finished stage's mean stands for its snapshots."""
    if not Path(mean).exists():
        return False
    recorded = dict(source.split() for source in read_checkpoint(mean).get("averaged_from", []))
    return list(recorded) == [Path(p).name for p in paths] and all(
        checkpoint_id(p) == recorded[Path(p).name] for p in paths if Path(p).exists())


def write_average(paths: list[str | os.PathLike], out: str | os.PathLike) -> None:
    """The mean of ``paths`` as a plain checkpoint (weights only), written atomically."""
    save_checkpoint(out, average_networks(paths), averaged_from=average_sources(paths))
