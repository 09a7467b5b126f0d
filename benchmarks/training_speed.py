#!/usr/bin/env python3
"""End-to-end training speed on the paper recipe's workload, with where the time goes.

The workload is the last stage of ``recipes/paper.toml`` (the shipped model's: the
``cpu-feedback`` network, worlds of 32/64/128/128 agents on 112-128 cells, 16 learners per world,
128-step rollouts, 3 epochs x 4 minibatches), from fresh weights. One episode set is timed after
a short warm-up (numba compiles the world's kernels once per process), split into acting (the
network's forward pass and sampling), the worlds (observations, frames, stepping) and learning
(the PPO update over the rollout, bootstrap value included):

    .venv/bin/python benchmarks/training_speed.py --threads 2 --steps 128

``--stage crowd --switch fov21`` times another stage, with one of the recipe's switches;
``--recipe paper-v6`` another recipe; ``--set update_precision=bf16`` changes a setting on top.
``--src DIR`` times another revision's ``src/`` with the same settings (what
``benchmarks/compare_revisions.py --benches training`` does). Run it on a quiet machine.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from collections import defaultdict
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def recipe_settings(stage: str | None, switch: str = "", recipe_name: str = "paper",
                    overrides: tuple[str, ...] = ()) -> dict:
    """A recipe stage's full training configuration (this tree's recipe, with ``switch`` if
    given and ``overrides`` (``KEY=VALUE``, as `formic train --set`) on top), as a plain dict,
    every setting that is off spelled as before None meant off (0, "", -1): a revision from
    before then (``--src``) reads it too."""
    import dataclasses

    from formic_trainer.config import OFF_SPELLINGS, parse_overrides
    from formic_trainer.recipes.definition import stage_config
    from formic_trainer.recipes.files import load_recipe

    recipe = load_recipe(recipe_name, switch)
    index = len(recipe.stages) - 1 if stage is None else [s.name for s in recipe.stages].index(stage)
    cfg = stage_config(recipe, index, Path(tempfile.gettempdir()), seed=1)
    cfg = dataclasses.replace(cfg, **parse_overrides(list(overrides)))
    return {key: OFF_SPELLINGS[key] if value is None and key in OFF_SPELLINGS else value
            for key, value in {**cfg.to_dict(), "init_weights": None}.items()}


def timed(owner, name: str, totals: dict[str, float], label: str) -> None:
    """Wrap ``owner.name`` so that its wall time adds up under ``label``."""
    original = getattr(owner, name)

    def wrapper(*args, **kwargs):
        started = time.perf_counter()
        try:
            return original(*args, **kwargs)
        finally:
            totals[label] += time.perf_counter() - started

    setattr(owner, name, wrapper)


def measure(settings: dict, threads: int, steps: int) -> dict:
    """Time one episode set in this process (whatever ``formic_trainer`` is on the path), its
    memory kept as `formic train` keeps it (a revision from before ``formic_runtime.memory``: as it was)."""
    try:
        from formic_runtime.memory import keep_freed_memory
    except ImportError:
        pass
    else:
        keep_freed_memory()
    from formic_trainer.actor import Actor
    from formic_trainer.config import TrainConfig, train_config_from_dict
    from formic_trainer.learner import Learner
    from formic_trainer.train import Trainer
    from formic_trainer.worlds import MetaAgents

    known = set(TrainConfig().to_dict())
    base = {k: v for k, v in settings.items() if k in known}
    warm = train_config_from_dict({**base, "threads": threads, "episode_steps": 8, "rollout_steps": 8})
    cfg = train_config_from_dict({**base, "threads": threads, "episode_steps": steps})
    totals: dict[str, float] = defaultdict(float)
    with tempfile.TemporaryDirectory() as run_dir:
        Trainer(warm, Path(run_dir) / "warm", resume=False, log=lambda *_: None).run_episode_set()
        trainer = Trainer(cfg, Path(run_dir) / "run", resume=False, log=lambda *_: None)
        for owner, name, label in ((Actor, "act", "acting"), (Actor, "rollout", "learning"),
                                   (MetaAgents, "observe", "worlds"), (MetaAgents, "step", "worlds"),
                                   (Learner, "learn", "learning")):
            timed(owner, name, totals, label)
        started, cpu_started = time.perf_counter(), time.process_time()
        trainer.run_episode_set()
        wall, cpu = time.perf_counter() - started, time.process_time() - cpu_started
    totals["other (Python loop, bookkeeping)"] = wall - sum(totals.values())
    return {"threads": threads, "episode_steps": steps, "agents": sum(cfg.teams),
            "learners": sum(n if cfg.learning_agents in (None, -1) else min(n, cfg.learning_agents)  # -1: --src
                            for n in cfg.teams),
            "agent_steps": trainer.env_steps, "wall_s": wall, "cpu_s": cpu,
            "agent_steps_per_s": trainer.env_steps / wall, "seconds": dict(totals)}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--threads", type=int, default=2, help="torch threads (the recipe trains with 1)")
    parser.add_argument("--steps", type=int, default=128, help="episode steps timed (one rollout per 128)")
    parser.add_argument("--stage", help="recipe stage whose settings to use (default: the last)")
    parser.add_argument("--switch", default="", help="one of the recipe's switches laid over it (e.g. fov21)")
    parser.add_argument("--recipe", default="paper", help="the recipe whose stage to time (default: paper)")
    parser.add_argument("--set", dest="overrides", action="append", default=[], metavar="KEY=VALUE",
                        help="a training setting over the stage's, e.g. update_precision=bf16 (repeatable)")
    parser.add_argument("--src", type=Path, help="another revision's src/ to time with these settings")
    parser.add_argument("--settings", type=Path, help=argparse.SUPPRESS)  # the child's side of --src
    parser.add_argument("--json", action="store_true", help="print one JSON object")
    args = parser.parse_args()
    if args.src is not None:  # the other revision runs in its own interpreter, on these settings
        with tempfile.NamedTemporaryFile("w", suffix=".json") as f:
            json.dump(recipe_settings(args.stage, args.switch, args.recipe, tuple(args.overrides)), f)
            f.flush()
            env = {**os.environ, "PYTHONPATH": str(args.src)}
            cmd = [sys.executable, __file__, "--settings", f.name, "--threads", str(args.threads),
                   "--steps", str(args.steps), "--json"]
            sys.exit(subprocess.run(cmd, env=env).returncode)
    settings = (json.loads(args.settings.read_text()) if args.settings
                else recipe_settings(args.stage, args.switch, args.recipe, tuple(args.overrides)))
    result = measure(settings, args.threads, args.steps)
    if args.json:
        print(json.dumps(result))
        return
    print(f"{result['agent_steps']:,} agent-steps ({result['agents']} agents, {result['learners']} learning) in "
          f"{result['wall_s']:.2f} s, {args.threads} thread(s): {result['agent_steps_per_s']:,.0f} agent-steps/s")
    for label, seconds in sorted(result["seconds"].items(), key=lambda kv: -kv[1]):
        print(f"  {label:34s} {seconds:6.2f} s  {100 * seconds / result['wall_s']:5.1f}%")


if __name__ == "__main__":
    main()
