#!/usr/bin/env python3
"""The facts of a recipe-built model, read from its run folder: the block of its model card.

    .venv/bin/python scripts/model_card.py models/training/recipe-paper/seed2                 # print the block
    .venv/bin/python scripts/model_card.py RUN --model models/formic_recipe.pt --write models/formic_recipe.md
    .venv/bin/python scripts/model_card.py RUN --model models/formic_recipe.pt --check models/formic_recipe.md

RUN is a ``formic train --recipe`` folder: ``recipe.json`` (the recipe, its seed, switch and
scale, and the stages it trained), each stage's ``config.json`` (the settings it trained with)
and ``progress.json`` (its counters; a run trained before the recipe wrote it: its ``latest.pt``),
``selection.json`` (the choice on validation) and ``model.pt``. The block names the
file (digest, size, network, parameters), the command that rebuilds it, each stage (episodes,
what it starts from, what it changes, agent-steps and CPU time), each candidate's validation
food and the choice, and what an empty pheromone channel costs the chosen one on validation.
``--model`` names the shipped copy, which must be the run's ``model.pt`` byte for byte.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "src"))

from formic_agent.checkpoint import load_network, read_checkpoint  # noqa: E402
from formic_eval.markdown_block import add_block_options, publish  # noqa: E402
from formic_eval.matrix import file_digest  # noqa: E402
from formic_trainer.config import PRESETS, off_as_none  # noqa: E402
from formic_trainer.recipes.files import held_identity  # noqa: E402


def markers(run: Path) -> tuple[str, str]:
    """The block's markers name its run, so that one page can hold the cards of several."""
    return f"<!-- card:begin (scripts/model_card.py {shown(run)}) -->", f"<!-- card:end {shown(run)} -->"

# settings every stage has its own value of, or that say nothing about what a stage trains
QUIET = {"seed", "init_weights", "total_episodes"}


def shown(path: Path) -> str:
    path = Path(path).resolve()
    return path.relative_to(ROOT).as_posix() if path.is_relative_to(ROOT) else str(path)


def value(v) -> str:
    if isinstance(v, (list, tuple)):
        return ",".join("-".join(map(str, x)) if isinstance(x, (list, tuple)) else str(x) for x in v)
    return str(v)


def changes(before: dict, after: dict) -> str:
    """The settings ``after`` changes from ``before``, as ``name=value``."""
    changed = [f"`{k}={value(after[k])}`" for k in after if k not in QUIET and value(after[k]) != value(before.get(k))]
    return ", ".join(changed) or "none"


def stage_rows(run: Path, stages: list[dict], preset: str) -> tuple[list[str], float]:
    rows = ["| stage | episodes | starts from | changes (from the previous stage; the first: from the preset) "
            "| agent-steps | CPU-h |", "|---|---|---|---|---|---|"]
    before, cpu_seconds = PRESETS[preset].__dict__, 0.0
    for stage in stages:
        folder = run / stage["name"]
        settings = off_as_none(json.loads((folder / "config.json").read_text()))
        progress = (json.loads((folder / "progress.json").read_text()) if (folder / "progress.json").exists()
                    else read_checkpoint(folder / "latest.pt")["progress"])
        mean = f", mean of episodes {stage['average'][0]}-{stage['episodes']} every {stage['average'][1]}" \
            if stage.get("average") else ""
        hours = progress["cpu_seconds"] / 3600
        rows.append(f"| {stage['name']} | {progress['episode']} of {stage['episodes']}{mean} | {stage['start']} "
                    f"| {changes(before, settings)} | {progress['env_steps']:,} | {hours:.2f} |")
        before, cpu_seconds = settings, cpu_seconds + progress["cpu_seconds"]
    return rows, cpu_seconds / 3600


def validation_rows(selection: dict) -> list[str]:
    teams = [str(n) for n in selection["validation"]["teams"]]
    rows = ["| candidate | " + " | ".join(f"{n} agents" for n in teams) + " | mean |",
            "|---|" + "---|" * (len(teams) + 1)]
    for name, found in selection["candidates"].items():
        label = f"**{name}** (chosen)" if name == selection["chosen"] else name
        rows.append(f"| {label} | " + " | ".join(f"{found['food_by_team'][n]:.1f}" for n in teams)
                    + f" | {found['food_mean']:.1f} |")
    empty = selection.get("channel_empty")
    if empty:
        rows.append("| chosen, pheromone channel empty | " + " | ".join(
            f"{empty['food_by_team'][n]:.1f} ({100 * empty['less_by_team'][n]:.0f}% less)" for n in teams)
            + f" | {empty['food_mean']:.1f} |")
    return rows


def card_block(run: Path, model: Path | None = None) -> list[str]:
    run = Path(run)
    claim = json.loads((run / "recipe.json").read_text())
    selection = json.loads((run / "selection.json").read_text())
    built = run / "model.pt"
    if model is not None and file_digest(model) != file_digest(built):
        raise SystemExit(f"{model} is not {built} (digests {file_digest(model)} and {file_digest(built)})")
    identity = json.loads(held_identity(claim))
    net, _ = load_network(built)
    network = read_checkpoint(built)["network"]
    parameters = sum(p.numel() for p in net.parameters())
    stages, hours = stage_rows(run, identity["stages"], identity["preset"])
    switch = f" --switch {claim['switch']}" if claim.get("switch") else ""
    scale = f" --scale {claim['scale']:g}" if claim.get("scale", 1) != 1 else ""
    recipe = Path(claim["recipe"]).stem
    validation = selection["validation"]
    return [
        f"**File.** `{shown(model or built)}`: digest `{file_digest(built)}`, {built.stat().st_size // 1024} kB, "
        f"{parameters:,} parameters; network {json.dumps(network)}. A plain checkpoint: tensors and primitives "
        "only, loaded with `torch.load(..., weights_only=True)`, its network configuration inside.",
        "",
        f"**Built by** `formic train --recipe {recipe}{switch}{scale} --seed {claim['seed']} --run-dir "
        f"{shown(run)}` (`recipes/{recipe}.toml`): {sum(s['episodes'] for s in identity['stages']):,} training "
        f"episodes, {hours:.2f} CPU-hours of training on one thread, {selection.get('cpu_hours', hours):.2f} "
        "with the validation.",
        "",
        *stages,
        "",
        f"**Chosen on validation**: {selection['rule']}. The validation set: {validation['scenarios']} "
        f"scenarios per team size, {validation['size']}x{validation['size']}, {validation['steps']} steps, "
        f"generated with seed {validation['seed']}, which no test set uses. Mean food per episode:",
        "",
        *validation_rows(selection),
    ]


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("run", type=Path, help="the formic train --recipe folder")
    parser.add_argument("--model", type=Path, help="the shipped copy of the run's model.pt")
    add_block_options(parser, "card")
    args = parser.parse_args()
    lines = card_block(args.run, args.model)
    return publish(lines, *markers(args.run), args, f"scripts/model_card.py {args.run}")


if __name__ == "__main__":
    sys.exit(main())
