"""How `formic train-ros --actors K` scales with K on this machine: one run per K of K worlds of
``--agents`` agents on ``--size`` squares, ``--rollout-steps``-step rollouts (two per episode),
``--episodes`` episodes per actor, every agent learning (the cpu preset). Prints per K the update
rate, agent-steps learned per second and the trainer's ``timing`` per update after the first
(away = weights crossing + acting + rollout crossing, gather = first to last actor's rollout,
learn = the update of all K rollouts joined, and publishing its weights). ``--learner-only``
also times the learner alone, in process, on K worlds' rollouts (the sizes K machines would
send)::

    .venv/bin/python benchmarks/actors_scaling.py --actors 1 2 4 --learner-only 1 2 4 8 16

Test and benchmark infrastructure, not part of the package (docs/training.md, "Actors: how
training scales with K").
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
from pathlib import Path


def scaling_config(actors: int, agents: int, size: int, rollout_steps: int):
    """``actors`` worlds of ``agents`` agents on a ``size`` square, episodes of two rollouts."""
    from formic_trainer.config import make_config

    return make_config("cpu", seed=3, teams=(agents,) * actors, world_sizes=((size, size),) * actors,
                       episode_steps=2 * rollout_steps, rollout_steps=rollout_steps)


def run_actors(actors: int, episodes: int, agents: int, size: int, rollout_steps: int, timeout_s: float,
               work: Path) -> dict:
    """One run of what `formic train-ros --actors K` launches (called directly, so that K = 1 also
    runs the actors' trainer and reports its timing); the trainer's timing per update."""
    from formic_ros.launch.actors import launch_actors_training
    from formic_ros.launch.launcher import TrainRunOptions

    opts = TrainRunOptions(config=scaling_config(actors, agents, size, rollout_steps),
                           run_dir=str(work / f"run_{actors}"), episodes=episodes * actors, fresh=True,
                           domain_id=150 + actors, timeout_s=timeout_s)
    result = launch_actors_training(opts, actors)
    timing = result["trainer"]["timing"]
    steps_per_update = actors * agents * rollout_steps
    return {"actors": actors, "exit_codes": result["exit_codes"], "agent_steps_per_update": steps_per_update,
            "timed_updates": timing["timed_updates"], "updates_per_s": round(timing["updates_per_s"], 3),
            "agent_steps_per_s": round(timing["updates_per_s"] * steps_per_update),
            **{key: round(value, 3) for key, value in timing.items() if key.endswith("_s") and key != "updates_per_s"}}


def learn_seconds(worlds: int, episodes: int, agents: int, size: int, rollout_steps: int, work: Path) -> dict:
    """The learner alone (in process, no ROS): mean seconds of one update of ``worlds`` worlds'
    rollouts (what the actors' trainer learns from at K = ``worlds``), over the updates after
    the first of ``episodes`` episodes; the sizes K machines would send."""
    from formic_trainer.train import Trainer, play_episode_set

    cfg = scaling_config(worlds, agents, size, rollout_steps)
    trainer = Trainer(cfg, work / f"learner_{worlds}", resume=False, log=lambda _text: None)
    seconds: list[float] = []

    def learn(rollout, env_steps: int) -> None:
        started = time.perf_counter()
        trainer.learner.learn(rollout, env_steps)
        seconds.append(time.perf_counter() - started)
        trainer.actor.weights_version = trainer.learner.version

    for episode in range(episodes):
        play_episode_set(cfg, trainer.envs, trainer.actor, episode, learn)
    trainer.close()
    steps = worlds * agents * rollout_steps
    return {"actors": worlds, "agent_steps_per_update": steps, "timed_updates": len(seconds) - 1,
            "learner_only_learn_s": round(sum(seconds[1:]) / (len(seconds) - 1), 3)}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python benchmarks/actors_scaling.py", description=__doc__.splitlines()[0])
    parser.add_argument("--actors", type=int, nargs="*", default=[1, 2, 4], help="K values run over ROS (none: skip)")
    parser.add_argument("--episodes", type=int, default=3, help="per actor (two updates each)")
    parser.add_argument("--agents", type=int, default=16, help="per actor (world), every one learning")
    parser.add_argument("--size", type=int, default=32, help="the worlds' side")
    parser.add_argument("--rollout-steps", type=int, default=128, help="an episode is two rollouts")
    parser.add_argument("--timeout-s", type=float, default=300.0, help="per run")
    parser.add_argument("--learner-only", type=int, nargs="*", default=[], metavar="K",
                        help="Also time the learner alone (no ROS) on K worlds' rollouts, e.g. 8 16.")
    parser.add_argument("--json", action="store_true", help="Print one JSON object per K.")
    args = parser.parse_args(argv)
    with tempfile.TemporaryDirectory() as tmp:
        for actors in args.actors:
            row = run_actors(actors, args.episodes, args.agents, args.size, args.rollout_steps, args.timeout_s,
                             Path(tmp))
            if args.json:
                print(json.dumps(row), flush=True)
            else:
                print(f"K={actors}: {row['updates_per_s']} updates/s, {row['agent_steps_per_s']} agent-steps/s, "
                      f"away {row['away_s']} s, gather {row['gather_s']} s, learn {row['learn_s']} s "
                      f"({row['agent_steps_per_update']} agent-steps an update, {row['timed_updates']} timed)",
                      flush=True)
        for worlds in args.learner_only:
            row = learn_seconds(worlds, 2, args.agents, args.size, args.rollout_steps, Path(tmp))
            print(json.dumps(row) if args.json else f"K={worlds}, learner alone: {row['learner_only_learn_s']} s "
                  f"an update of {row['agent_steps_per_update']} agent-steps ({row['timed_updates']} timed)",
                  flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
