"""Readable episode summaries: food over time and what each agent did."""

from __future__ import annotations

import click
import numpy as np


def episode_summary(scenario, policy: str, result) -> dict:
    cfg = scenario.config
    curve = result.food_curve
    marks = sorted({min(len(curve), m) for m in (64, 128, 256, 384, 512, 768, 1024, len(curve))})
    return {
        "policy": policy if isinstance(policy, str) else policy.describe(),
        "seed": scenario.seed,
        "size": [cfg.height, cfg.width],
        "agents": cfg.n_agents,
        "resources": len(scenario.resources),
        "steps": len(curve),
        "food": float(result.food),
        "food_over_time": {str(m): float(curve[m - 1]) for m in marks if m > 0},
        "per_agent": {
            "collected": result.collected.round(3).tolist(),
            "delivered": result.delivered.round(3).tolist(),
            "queued_steps": result.queued_steps.tolist(),
        },
        "step_ms_mean": result.step_ms_mean,
        "world_step_ms_mean": float(result.step_seconds.mean() * 1e3),
        "state_digest": result.world.state_digest(),
    }


def print_episode_summary(summary: dict) -> None:
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
