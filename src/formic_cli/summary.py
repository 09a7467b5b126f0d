"""Readable episode summaries (built by ``formic_runtime.episode.EpisodeStats.summary``):
food over time and what each agent did."""

from __future__ import annotations

import json

import click


def emit_json(obj: dict) -> None:
    """The ``--json`` output of every command: one JSON object on stdout (numbers that JSON
    does not know, such as NumPy's, as floats; anything else, such as paths, as text)."""
    click.echo(json.dumps(obj, default=_plain))


def _plain(value) -> float | str:
    try:
        return float(value)
    except (TypeError, ValueError):
        return str(value)


def print_episode_summary(summary: dict) -> None:
    import numpy as np

    h, w = summary["size"]
    click.echo(
        f"{summary['policy']} | {h}x{w} world, {summary['agents']} agents, "
        f"{summary['resources']} resources, seed {summary['seed']}, {summary['steps']} steps"
    )
    click.echo(f"food deposited: {summary['food']:.1f}")
    click.echo("food over time: " + "  ".join(f"t={k}: {v:.1f}" for k, v in summary["food_over_time"].items()))
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
    click.echo(f"decision time {summary['step_ms_mean']:.2f} ms/step, world {summary['world_step_ms_mean']:.2f} ms/step")
    for kind, path in summary.get("files", {}).items():
        click.echo(f"{kind}: {path}")
