"""How the commands report: the ``--json`` object, readable episode summaries (built by
``formic_runtime.episode.EpisodeStats.summary``: food over time and what each agent did) and
errors as click messages."""

from __future__ import annotations

import sys
from collections.abc import Callable
from contextlib import contextmanager

import click

from formic_runtime.json_output import emit_json


def emit(as_json: bool, obj: dict, human: str | Callable[[dict], None]) -> None:
    """``obj`` as JSON, or else the human summary: a text, or a function printing ``obj``."""
    if as_json:
        emit_json(obj)
    elif callable(human):
        human(obj)
    else:
        click.echo(human)


@contextmanager
def click_errors(*kinds: type[Exception], prefix: str = "", interrupted: str | None = None):
    """Report these exceptions as a click error (message, exit status 1); with ``interrupted``,
    Ctrl-C exits with status 130, printing that text (if any) on stderr."""
    try:
        yield
    except kinds as exc:
        raise click.ClickException(f"{prefix}{exc}") from exc
    except KeyboardInterrupt:
        if interrupted is None:
            raise
        if interrupted:
            click.echo(interrupted, err=True)
        sys.exit(130)


def print_episode_summary(summary: dict) -> None:
    import numpy as np

    h, w = summary["size"]
    click.echo(
        f"{summary['policy']} | {h}x{w} world, {summary['agents']} agents, "
        f"{summary['resources']} resources, seed {summary['seed']}, {summary['steps']} steps"
    )
    click.echo(f"food deposited: {summary['food']:.1f}")
    click.echo("food over time: "
               + "  ".join(f"t={k}: {v:.1f}" for k, v in summary["food_over_time"].items()))
    per = summary["per_agent"]
    delivered = np.array(per["delivered"])
    active = int((np.array(per["collected"]) > 0).sum())
    click.echo(
        f"agents: {active}/{len(delivered)} collected food; delivered per agent "
        f"min {delivered.min():.1f} / mean {delivered.mean():.2f} / max {delivered.max():.1f}; "
        f"mean steps queued {np.mean(per['queued_steps']):.0f}"
    )
    top = np.argsort(-delivered)[:5]
    click.echo("top agents: " + ", ".join(f"#{a}: {delivered[a]:.1f}" for a in top))
    click.echo(f"decision time {summary['step_ms_mean']:.2f} ms/step, "
               f"world {summary['world_step_ms_mean']:.2f} ms/step")
    for kind, path in summary.get("files", {}).items():
        click.echo(f"{kind}: {path}")
