"""Actors across a lossy link (root only): the trainer on one simulated machine, two actors on
the other, joined by :mod:`benchmarks.netsim`'s forwarder (20 ms each way, 2% loss) and the same
layout on a clean link. Prints each link's update rate, their ratio, rollouts dropped and lost,
the bytes of a rollout and a weights message, and where an update's time goes (the trainer's
``timing``: away = weights crossing + acting + rollout crossing, gather, learn)::

    sudo .venv/bin/python benchmarks/actors_link.py --episodes 4

Test and benchmark infrastructure, not part of the package (docs/ros.md, "Actors").
"""

from __future__ import annotations

import argparse
import json
import os
import signal
import sys

if __package__ in (None, ""):
    sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))

from benchmarks.netsim import Link, _json_lines, _link_environments, run_on_link  # noqa: E402

ACTORS = 2


def actors_link_config(worlds: int = ACTORS, rollout_steps: int = 16, agents: int = 4, size: int = 20):
    """``worlds`` worlds of ``agents`` agents on a ``size`` square, episodes of two
    ``rollout_steps``-step rollouts (the cpu preset: every agent learns)."""
    from formic_trainer.config import make_config

    return make_config("cpu", seed=3, teams=(agents,) * worlds, world_sizes=((size, size),) * worlds,
                       episode_steps=2 * rollout_steps, rollout_steps=rollout_steps, team_reward=0.25)


def actors_across_link(episodes: int = 4, delay_ms: float = 20.0, loss: float = 0.02, link_seed: int = 1,
                       rollout_steps: int = 16, agents: int = 4, size: int = 20, domain_id: int = 149,
                       prefix: str = "fxa", net: int = 219, limit_s: float = 240.0, workdir: str = "/tmp") -> dict:
    """``formic trainer --actors 2`` in namespace a, ``formic actor --actor 0`` and ``--actor 1``
    in b, ``episodes`` episodes per actor of :func:`actors_link_config` over a link with
    ``delay_ms`` each way and ``loss``. Returns the trainer's result (with ``timing``), the
    actors' results, every process's exit code (None: still running at ``limit_s``, then
    killed) and ``link``; the logs stay in ``workdir``. Namespaces and processes are removed
    in any case."""
    cfg = actors_link_config(rollout_steps=rollout_steps, agents=agents, size=size)
    chunks = cfg.episode_steps // cfg.rollout_steps
    config_file = os.path.join(workdir, f"{prefix}_config.json")
    with open(config_file, "w") as fh:
        json.dump(cfg.to_dict(), fh)
    train = ["--train-config", config_file]
    commands = {"trainer": ("a", ["trainer", *train, "--run-dir", os.path.join(workdir, f"{prefix}_run"), "--fresh",
                                  "--actors", str(ACTORS), "--max-updates", str(episodes * chunks), "--json"])}
    for actor in range(ACTORS):
        commands[f"actor{actor}"] = ("b", ["actor", *train, "--actor", str(actor), "--episodes", str(episodes),
                                           "--startup-timeout", str(limit_s / 2), "--timeout", str(limit_s),
                                           "--json"])
    with Link(prefix, delay_ms=delay_ms, loss=loss, seed=link_seed, net=net) as link:
        envs = dict(zip("ab", _link_environments(link, domain_id, False, workdir)))
        texts, exit_codes, elapsed = run_on_link(link, envs, commands, tuple(commands), limit_s, workdir)
    results = {name: (lines[-1] if (lines := _json_lines(text)) else None) for name, text in texts.items()}
    return {"trainer": results.pop("trainer"), "actors": results, "exit_codes": exit_codes,
            "link": {"delay_ms": delay_ms, "loss": loss, "seed": link_seed, "wall_s": round(elapsed, 1)}}


def message_bytes(rollout_steps: int = 16, agents: int = 4, size: int = 20) -> dict:
    """Serialized (CDR) bytes of an actor's rollout (``agents`` x ``rollout_steps`` steps, compact observations,
    taken from ``formic train``'s own first rollout of the first world) and of a weights message
    of :func:`actors_link_config`'s network."""
    import hashlib
    import tempfile
    from pathlib import Path

    from rclpy.serialization import serialize_message

    from formic_agent.checkpoint import state_dict_bytes
    from formic_ros.convert_learning import WeightsPayload, encode_rollout, encode_weights
    from formic_trainer.train import Trainer, play_episode_set

    one_world = actors_link_config(worlds=1, rollout_steps=rollout_steps, agents=agents, size=size)
    with tempfile.TemporaryDirectory() as run_dir:
        trainer = Trainer(one_world, Path(run_dir), resume=False, log=lambda _text: None)
        rollouts = []
        play_episode_set(one_world, trainer.envs, trainer.actor, 0, lambda rollout, _steps: rollouts.append(rollout))
        data = state_dict_bytes(trainer.net)
        weights = encode_weights(WeightsPayload(1, data, hashlib.sha256(data).hexdigest()[:12],
                                                trainer.net.config.to_dict()))
        trainer.close()
    return {"rollout": len(serialize_message(encode_rollout(rollouts[0]))), "weights": len(serialize_message(weights))}


def summary(result: dict) -> dict:
    """The figures of one run: update rate, dropped and lost rollouts, the cycle's phases."""
    trainer = result["trainer"] or {}
    timing = trainer.get("timing", {})
    return {"link": result["link"], "exit_codes": result["exit_codes"], "updates": trainer.get("updates"),
            "dropped": trainer.get("dropped"), "lost": trainer.get("lost"),
            "updates_per_s": timing.get("updates_per_s"),
            "seconds_per_update": {key: round(value, 4) for key, value in timing.items()
                                   if key.endswith("_s") and key != "updates_per_s"},
            "missed_actions": [e["missed_actions"] for r in result["actors"].values() if r for e in r["episodes"]]}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python benchmarks/actors_link.py", description=__doc__.splitlines()[0])
    parser.add_argument("--episodes", type=int, default=4, help="per actor (two updates each)")
    parser.add_argument("--rollout-steps", type=int, default=16, help="an episode is two rollouts")
    parser.add_argument("--agents", type=int, default=4, help="per actor (world), every one learning")
    parser.add_argument("--size", type=int, default=20, help="the worlds' side")
    parser.add_argument("--delay-ms", type=float, default=20.0)
    parser.add_argument("--loss", type=float, default=0.02)
    parser.add_argument("--limit-s", type=float, default=240.0, help="per run")
    parser.add_argument("--workdir", default="/tmp", help="logs and run directories go here")
    args = parser.parse_args(argv)
    signal.signal(signal.SIGTERM, lambda *_: sys.exit(143))  # a SIGTERM still removes namespaces and processes
    runs = {}
    for name, delay_ms, loss, prefix, net in (("clean", 0.0, 0.0, "fxac", 220), ("lossy", args.delay_ms, args.loss,
                                                                                  "fxal", 221)):
        runs[name] = summary(actors_across_link(args.episodes, delay_ms, loss, rollout_steps=args.rollout_steps,
                                                agents=args.agents, size=args.size, prefix=prefix, net=net,
                                                limit_s=args.limit_s, workdir=args.workdir))
        print(json.dumps({name: runs[name]}), flush=True)
    rates = [runs[name]["updates_per_s"] for name in ("clean", "lossy")]
    ratio = rates[1] / rates[0] if all(rates) else None
    print(json.dumps({"rate_ratio": ratio, "message_bytes": message_bytes(args.rollout_steps, args.agents, args.size)}),
          flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
