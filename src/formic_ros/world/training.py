"""Distributed training's world: the world node playing episode after episode on the scenarios
the in-process trainer would draw, with the training masks in the observation batches."""

from __future__ import annotations

from dataclasses import replace
from typing import TYPE_CHECKING, Callable

import formic_topics as topics

from ..graph import publishers_of
from .node import WorldNode
from .options import WorldNodeOptions

if TYPE_CHECKING:
    from formic_trainer.config import TrainConfig


def require_one_world(cfg: TrainConfig) -> None:
    """A world node serves one world: distributed training needs one meta-agent team."""
    if len(cfg.teams) != 1:
        raise ValueError(f"distributed training runs one meta-agent world; teams={list(cfg.teams)} "
                         "(give it one team size, e.g. teams=16)")


def why_hosts_silent(node: WorldNode) -> str:
    """Why no learning host answered step 0, naming the peers: the drivers that claimed agents
    (or that none did), and the trainer whose weights a learning host waits for before it acts
    (a rollout or weights lost between machines stalls the host, not the world)."""
    drivers = node.ownership.why_nobody_answered() or (
        "no learning host claimed agents (check --domain-id, --namespace, ROS_STATIC_PEERS)")
    topic = topics.full_name(node.get_namespace(), topics.WEIGHTS)
    trainers = publishers_of(node, topic)
    if trainers:
        return f"{drivers}; a learning host acts only on weights from {', '.join(trainers)} (see its log)"
    return f"{drivers}; no trainer publishes on {topic}, and a learning host acts only on its weights"


def serve_training_world(
    cfg: TrainConfig,
    episodes: int,
    options: WorldNodeOptions,
    first_episode: int = 0,
    domain_id: int | None = None,
    on_episode: Callable[[dict], None] | None = None,
    world_index: int | None = None,
) -> list[dict]:
    """Distributed training's world: ``episodes`` episodes, each on a new scenario drawn as the
    in-process trainer draws them (:func:`formic_trainer.worlds.sample_scenarios` from the
    episode's scenario stream: world size, obstacles, curriculum intensities,
    training start), with the training masks in the observations. One meta-agent world: the
    configuration's ``teams`` must hold one team. ``on_episode`` gets each episode's summary
    (with ``episode``, the global episode number, and the curriculum's intensities).
    ``world_index``: an actor's world (``formic train-ros --actors K``): world ``world_index``
    of each episode set's meta-agent worlds, whose global episodes step by their number, as
    ``formic train`` counts them."""
    from formic_trainer.config import require_distributable
    from formic_trainer.worlds import sample_scenarios, scenario_rng

    from ..env import ros_session
    from .lock import world_lock

    require_distributable(cfg)
    if world_index is None:
        require_one_world(cfg)
    stride = 1 if world_index is None else len(cfg.teams)
    options = replace(options, training_masks=True, policy_label=options.policy_label or "formic:learning")
    summaries = []
    with world_lock(options.namespace, domain_id), ros_session(domain_id) as executor:
        node = None
        last_episode = first_episode + (episodes - 1) * stride
        for episode in range(first_episode, last_episode + 1, stride):
            scenarios, highway, deposit = sample_scenarios(cfg, scenario_rng(cfg, episode), episode)
            scenario = scenarios[world_index or 0]
            if node is None:
                node = WorldNode(scenario, options, why_absent=why_hosts_silent)
                executor.add_node(node)
            else:
                node.load(scenario)
            summary = node.run(executor, last=episode == last_episode)
            summary.update(episode=episode, highway_intensity=highway, deposit_strength=deposit)
            summaries.append(summary)
            if on_episode is not None:
                on_episode(summary)
    return summaries
