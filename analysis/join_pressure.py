"""Which loss term moves P(JOIN) where JOIN is valid, and which way.

Plays training episodes (the run's own worlds, actor and rollout chunks, by default one
128-agent world with 16 learners, the control recipe of models/formic_paper.md), then, without
updating, takes each loss term's gradient over the chunks and its first-order effect on the mean
probability of JOIN over the free steps where JOIN is valid: ``-grad(term) . grad(P)`` per unit
step for a plain gradient step, and with ``--optimizer-state`` (a run's ``latest.pt``) also for
an Adam step preconditioned by that run's second moments (momentum left out). The terms add up:
the ``all`` row is their sum. With ``--split`` each effect is also split by the steps its
gradient comes from: where JOIN is valid, where it was tried and is not, where a move was chosen
and JOIN is not valid (the three add up to the whole).

Usage (the run's checkpoint is in the history, no longer in the tree):
       git show 57b96f9:models/training/paper-sharp2/latest.pt > /tmp/paper-sharp2.pt
       .venv/bin/python analysis/join_pressure.py --model models/formic_paper.pt \
           --optimizer-state /tmp/paper-sharp2.pt [--set valid_coef=0.1]
"""

from __future__ import annotations

import json
from pathlib import Path

import click
import numpy as np
import torch

from formic_agent.checkpoint import load_network
from formic_cli.options import training_config
from formic_trainer.actor import Actor
from formic_trainer.algorithm import policy_losses, update_tensors
from formic_trainer.train import play_episode_set
from formic_trainer.worlds import MetaAgents

CONTROL = ("network=cpu-feedback", "seed=12", "rewards=reference", "training_filter=reference", "learning_agents=16",
           "filter_anneal_start=0", "filter_anneal_end=1", "curriculum=false", "teams=128", "world_sizes=128-128",
           "lr=0.00005", "entropy_coef=0.002")
TERMS = ("policy", "entropy", "valid", "value")


def rollout_batches(cfg, net, episodes: int) -> list[dict[str, torch.Tensor]]:
    """The learners' rollout chunks of ``episodes`` episode sets, as the learner's loss reads them."""
    envs = MetaAgents(cfg)
    actor = Actor(cfg, net, np.arange(envs.n_agents))
    chunks = []
    for episode in range(episodes):
        play_episode_set(cfg, envs, actor, episode, lambda rollout, _env_steps: chunks.append(rollout))
    return [update_tensors(cfg, chunk) for chunk in chunks]


# Where a term's gradient comes from: the free steps of the rollout, split three ways.
SOURCES = {
    "JOIN valid": lambda b: b["train_mask"][..., 4],
    "JOIN tried, invalid": lambda b: ~b["train_mask"][..., 4] & (b["actions"] == 4),
    "move, JOIN invalid": lambda b: ~b["train_mask"][..., 4] & (b["actions"] != 4),
}


def term_gradients(cfg, net, batches, source=None) -> dict[str, list[torch.Tensor]]:
    """Each weighted loss term's gradient (as it enters the loss), summed over the batches; with
    ``source`` (a SOURCES entry) only the part that comes from those steps (the parts add up)."""
    params = list(net.parameters())
    weight = {"policy": 1.0, "entropy": -cfg.entropy_coef, "valid": cfg.valid_coef, "value": cfg.value_coef}
    sums = {name: [torch.zeros_like(p) for p in params] for name in TERMS}
    for batch in batches:
        scale = dict.fromkeys(TERMS, 1.0)
        if source is not None:
            where = source(batch).float()
            value_mask = batch["value_mask"] if cfg.queued_value_loss else batch["loss_mask"] * batch["value_mask"]
            share = float((batch["loss_mask"] * where).sum() / batch["loss_mask"].sum().clamp(min=1.0))
            scale = dict.fromkeys(TERMS, share)
            scale["value"] = float((value_mask * where).sum() / value_mask.sum().clamp(min=1.0))
            batch = dict(batch, loss_mask=batch["loss_mask"] * where, value_mask=batch["value_mask"] * where)
        terms = policy_losses(net, cfg, batch)
        for name in TERMS:
            grads = torch.autograd.grad(weight[name] * scale[name] * terms[name], params, retain_graph=True,
                                        allow_unused=True)
            for total, g in zip(sums[name], grads):
                if g is not None:
                    total += g
    return sums


def join_probability_gradient(net, batches) -> tuple[float, int, list[torch.Tensor]]:
    """Mean P(JOIN) over the free steps where JOIN is valid, how many, and its gradient."""
    params = list(net.parameters())
    chosen = []
    for batch in batches:
        logits, _, _ = net(batch["observations"], (batch["h0"], batch["c0"]), batch["extra_inputs"])
        where = batch["train_mask"][..., 4] & (batch["loss_mask"] > 0)
        chosen.append(torch.softmax(logits, dim=-1)[..., 4][where])
    p = torch.cat(chosen)
    grads = torch.autograd.grad(p.mean(), params, allow_unused=True)
    return float(p.detach().mean()), len(p), [torch.zeros_like(q) if g is None else g for q, g in zip(params, grads)]


def effects(grads: dict[str, list[torch.Tensor]], direction: list[torch.Tensor],
            precondition: list[torch.Tensor] | None = None) -> dict[str, float]:
    """First-order change of the measured probability per unit step down each term's gradient."""
    scale = precondition or [1.0] * len(direction)
    out = {name: -sum(float((g * s * d).sum()) for g, s, d in zip(grads[name], scale, direction)) for name in TERMS}
    out["all"] = sum(out.values())
    return out


@click.command()
@click.option("--model", required=True, type=click.Path(exists=True, dir_okay=False))
@click.option("--episodes", default=2, show_default=True, help="Episode sets to roll out.")
@click.option("--set", "overrides", multiple=True, help="Training config FIELD=VALUE over the control recipe.")
@click.option("--optimizer-state", type=click.Path(exists=True, dir_okay=False),
              help="A run's checkpoint whose Adam second moments precondition the step.")
@click.option("--split", is_flag=True, help="Also split each effect by the steps it comes from (SOURCES).")
@click.option("--out", type=click.Path(dir_okay=False), help="Also write the result here as JSON.")
def main(model, episodes, overrides, optimizer_state, split, out) -> None:
    torch.set_num_threads(1)
    cfg = training_config("cpu", None, CONTROL + tuple(overrides))
    net, _ = load_network(model)
    batches = rollout_batches(cfg, net, episodes)
    p_join, states, direction = join_probability_gradient(net, batches)
    precondition = None
    if optimizer_state:
        state = torch.load(optimizer_state, weights_only=True)["optimizer"]["state"]
        eps = 1e-5  # the cpu preset's Adam epsilon
        precondition = [1.0 / (state[i]["exp_avg_sq"].sqrt() + eps) for i in range(len(direction))]
    result = {"model": model, "episodes": episodes, "overrides": list(overrides), "join_valid_steps": states,
              "p_join": p_join}
    click.echo(f"{states} free steps where JOIN is valid, mean P(JOIN) {p_join:.3f}; first-order change per unit step:")
    for label, source in (("all steps", None), *(SOURCES.items() if split else ())):
        grads = term_gradients(cfg, net, batches, source)
        row = {"plain": effects(grads, direction)}
        if precondition is not None:
            row["adam"] = effects(grads, direction, precondition)
        result[label] = row
        click.echo(f" from {label}:")
        for name in (*TERMS, "all"):
            adam = f"   Adam-preconditioned {row['adam'][name]:+.3e}" if "adam" in row else ""
            click.echo(f"  {name:8s} plain {row['plain'][name]:+.3e}{adam}")
    if out:
        Path(out).write_text(json.dumps(result, indent=1))


if __name__ == "__main__":
    main()
