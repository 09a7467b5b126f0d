"""Actors: ``formic train-ros --actors K`` (K actors and the trainer on this machine) and the
specs ``formic actor`` and ``formic trainer --actors K`` run on several machines.

An actor is world ``k`` of the configuration's meta-agent worlds (the world node in training
mode) and the learning host that acts in it, in namespace ``NS/actorK`` (one world per
namespace on a machine); the host sends its rollouts to, and takes weights from, the trainer in
``NS`` (:mod:`formic_ros.drivers.actors_trainer`: synchronous updates, every actor's rollout of
the current weights joined into ``formic train``'s one rollout; or, with the hosts on
``--switch-weights newest``, asynchronous ones, one an actor's rollout).
"""

from __future__ import annotations

import json
import math
import time
from dataclasses import asdict

import formic_topics as topics

from ..drivers.lag import AHEAD_CHUNKS
from ..env import check_domain_id, ros_environment, warn_if_exposed
from ..world.lock import check_world_free
from ..world.options import WorldNodeOptions
from .launcher import EPISODE_FIELDS, HOST_EXIT_S, TrainRunOptions, first_episode
from .node_process import node_spec
from .processes import Children, JsonLines, watch

ACTOR_DEADLINE_S = 30.0  # the trainer leaves out of an update an actor silent this long after the first rollout
HOST = "learning_host"  # an actor's learning host's node name (in the actor's namespace)


def actor_namespace(namespace: str, actor: int) -> str:
    return topics.full_name(namespace, f"actor{actor}")


def episodes_per_actor(opts: TrainRunOptions, actors: int) -> int:
    """Environment episodes (``opts.episodes``, all worlds together, as ``formic train`` counts
    them) over ``actors`` actors, one world each."""
    worlds = len(opts.config.teams)
    if actors != worlds:
        raise ValueError(f"--actors {actors} for {worlds} worlds (teams={list(opts.config.teams)}): one actor a world")
    if opts.episodes % actors:
        raise ValueError(f"--episodes {opts.episodes} over {actors} actors: a multiple of {actors} (an episode each)")
    return opts.episodes // actors


def trainer_spec(opts: TrainRunOptions, config_file: str, actors: int, deadline_s: float = ACTOR_DEADLINE_S) -> dict:
    """The trainer of ``actors`` actors: it leaves after their episodes' updates (synchronous:
    one an actors' chunk) or rollouts (asynchronous, hosts on ``switch="newest"``: one update a
    rollout, a rollout too old dropped)."""
    rollouts = episodes_per_actor(opts, actors) * math.ceil(opts.config.episode_steps / opts.config.rollout_steps)
    # asynchronous: a host sends at most AHEAD_CHUNKS rollouts a weights version, so with K actors a
    # rollout lags about AHEAD_CHUNKS x K versions at most; twice that before one is dropped
    ends = ({"max_updates": rollouts} if opts.switch == "chunk"
            else {"max_rollouts": rollouts * actors, "max_lag": 2 * AHEAD_CHUNKS * actors})
    return node_spec("trainer", train_config=config_file, namespace=opts.namespace, domain_id=opts.domain_id,
                     run_dir=opts.run_dir, resume=not opts.fresh, actors=actors, actor_deadline_s=deadline_s,
                     synchronous=opts.switch == "chunk", **ends)


def actor_specs(opts: TrainRunOptions, config_file: str, actor: int, episodes: int, start: int) -> dict[str, dict]:
    """Actor ``actor``'s world and learning host, ``episodes`` episodes from global episode ``start``."""
    namespace = actor_namespace(opts.namespace, actor)
    world = WorldNodeOptions(namespace=namespace, deadline_s=opts.deadline_ms / 1e3,
                             startup_timeout_s=opts.startup_timeout_s, viewer_every=opts.viewer_every,
                             external=(), drivers=(topics.full_name(namespace, HOST),))
    return {
        f"world{actor}": node_spec("world", train_config=config_file, episodes=episodes, first_episode=start,
                                   options=asdict(world), domain_id=opts.domain_id, world_index=actor),
        f"host{actor}": node_spec("learning_agents", train_config=config_file, namespace=namespace,
                                  domain_id=opts.domain_id, agent_ids=list(range(opts.config.teams[actor])),
                                  switch=opts.switch, episodes=episodes, first_episode=start, name=HOST,
                                  world_index=actor, trainer_namespace=opts.namespace),
    }


def launch_actors_training(opts: TrainRunOptions, actors: int) -> dict:
    """``formic train-ros --actors K``: the trainer and K actors (one world each) as separate
    processes on this machine; returns each world's episode summaries (with ``actor``) and the
    trainer's result. Children are stopped and reaped in any case."""
    per_actor = episodes_per_actor(opts, actors)
    check_domain_id(opts.domain_id)
    for actor in range(actors):
        check_world_free(actor_namespace(opts.namespace, actor), opts.domain_id)
    start = first_episode(opts.run_dir, opts.fresh)
    started = time.monotonic()
    warn_if_exposed()
    with Children("formic-actors-", ros_environment(opts.domain_id), opts.log_dir) as run:
        config_file = run.dir / "train_config.json"
        config_file.write_text(json.dumps(opts.config.to_dict()))
        trainer_out = run.stdout("trainer")
        trainer = run.start("trainer", trainer_spec(opts, str(config_file), actors), trainer_out)
        world_lines, children = {}, []
        for actor in range(actors):
            for name, spec in actor_specs(opts, str(config_file), actor, per_actor, start).items():
                out = run.stdout(name) if name.startswith("world") else None
                children.append(run.start(name, spec, out))
                if out is not None:
                    world_lines[actor] = JsonLines(out)
        episodes: list[dict] = []

        def collect_episodes() -> None:
            for actor, lines in world_lines.items():
                for summary in lines.new():
                    episodes.append({"actor": actor} | {key: summary[key] for key in EPISODE_FIELDS})
                    if opts.on_episode is not None:
                        opts.on_episode(summary)

        watch(trainer, children, opts.timeout_s, "training", poll_s=0.5, tick=collect_episodes)
        collect_episodes()
        result = JsonLines(trainer_out).new()[-1]
        leave_by = time.monotonic() + HOST_EXIT_S
        for child in children:
            child.wait(leave_by - time.monotonic())
    episodes.sort(key=lambda e: (e["episode"], e["actor"]))
    return {"run_dir": opts.run_dir, "first_episode": start, "actors": actors, "episodes": episodes,
            "trainer": result, "launch_wall_s": time.monotonic() - started, "exit_codes": run.codes}


def launch_actor(opts: TrainRunOptions, actor: int, start: int) -> dict:
    """``formic actor``: actor ``actor`` (world and learning host) for a trainer elsewhere, on
    ``opts.episodes`` episodes of its world from global episode ``start``; returns the world's
    episode summaries. Children are stopped and reaped in any case."""
    if not 0 <= actor < len(opts.config.teams):
        raise ValueError(f"actor {actor}: the config has worlds 0-{len(opts.config.teams) - 1}")
    check_domain_id(opts.domain_id)
    check_world_free(actor_namespace(opts.namespace, actor), opts.domain_id)
    warn_if_exposed()
    with Children(f"formic-actor{actor}-", ros_environment(opts.domain_id), opts.log_dir) as run:
        config_file = run.dir / "train_config.json"
        config_file.write_text(json.dumps(opts.config.to_dict()))
        world_out = run.stdout("world")
        specs = actor_specs(opts, str(config_file), actor, opts.episodes, start)
        world = run.start(f"world{actor}", specs[f"world{actor}"], world_out)
        host = run.start(f"host{actor}", specs[f"host{actor}"])
        lines, episodes = JsonLines(world_out), []

        def collect_episodes() -> None:
            for summary in lines.new():
                episodes.append({"actor": actor} | {key: summary[key] for key in EPISODE_FIELDS})
                if opts.on_episode is not None:
                    opts.on_episode(summary)

        watch(world, [host], opts.timeout_s, f"actor {actor}", poll_s=0.5, tick=collect_episodes)
        collect_episodes()
        host.wait(HOST_EXIT_S)
    return {"actor": actor, "first_episode": start, "episodes": episodes, "exit_codes": run.codes}
