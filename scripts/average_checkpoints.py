"""Average the weights of checkpoints of one run (stochastic weight averaging, offline;
``formic_trainer.averaging``, which ``formic train --recipe`` uses too). The inputs must share
one network configuration; the output is a plain checkpoint (weights only) naming its inputs
by content hash.

    .venv/bin/python scripts/average_checkpoints.py --out models/formic_paper.pt run/ep200.pt run/ep208.pt ...
"""

from __future__ import annotations

import click

from formic_agent.checkpoint import CheckpointError
from formic_trainer.averaging import write_average


@click.command()
@click.argument("checkpoints", nargs=-1, required=True, type=click.Path(exists=True, dir_okay=False))
@click.option("--out", required=True, type=click.Path(dir_okay=False), help="The averaged checkpoint.")
def main(checkpoints: tuple[str, ...], out: str) -> None:
    """Write the mean of CHECKPOINTS' weights to --out."""
    try:
        write_average(list(checkpoints), out)
    except CheckpointError as exc:
        raise click.ClickException(str(exc)) from exc
    click.echo(f"{out}: the mean of {len(checkpoints)} checkpoints")


if __name__ == "__main__":
    main()
