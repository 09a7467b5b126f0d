"""Average the weights of checkpoints of one run (stochastic weight averaging, offline).

A policy trained with every team size at once swings from one checkpoint to the next (the
128-agent food most); the mean of the last few checkpoints of one run, whose weights lie in
one basin, is steadier than any one of them. The inputs must share one network configuration;
the output is a plain checkpoint (weights only) naming its inputs by content hash.

    .venv/bin/python scripts/average_checkpoints.py --out models/formic_paper.pt run/ep200.pt run/ep208.pt ...
"""

from __future__ import annotations

from pathlib import Path

import click
import torch

from formic_agent.checkpoint import CheckpointError, checkpoint_id, load_network, save_checkpoint


def average_networks(paths: list[str]):
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


@click.command()
@click.argument("checkpoints", nargs=-1, required=True, type=click.Path(exists=True, dir_okay=False))
@click.option("--out", required=True, type=click.Path(dir_okay=False), help="The averaged checkpoint.")
def main(checkpoints: tuple[str, ...], out: str) -> None:
    """Write the mean of CHECKPOINTS' weights to --out."""
    try:
        net = average_networks(list(checkpoints))
    except CheckpointError as exc:
        raise click.ClickException(str(exc)) from exc
    save_checkpoint(out, net, averaged_from=[f"{Path(p).name} {checkpoint_id(p)}" for p in checkpoints])
    click.echo(f"{out}: the mean of {len(checkpoints)} checkpoints")


if __name__ == "__main__":
    main()
