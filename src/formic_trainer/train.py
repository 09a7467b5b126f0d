"""ForMIC training, top to bottom: worlds -> actor -> world.step -> learner.

The meta-agent worlds step together, one :class:`Actor` acts for all their agents and every
``rollout_steps`` steps the :class:`Learner` updates the network they share from the actor's
:class:`Rollout`.
``formic train-ros`` runs the same actor in a ROS learning host and the same learner in the
trainer node (:mod:`formic_ros.drivers.learning_host`, :mod:`formic_ros.drivers.trainer`).
"""

from __future__ import annotations

import time
from collections.abc import Callable
from pathlib import Path

import numpy as np

from formic_agent.checkpoint import load_network, save_checkpoint
from formic_runtime.signals import STOP_SIGNALS, StopBetweenSteps, handling

from .actor import Actor, filter_probability
from .config import TrainConfig
from .learner import Learner
from .rollout import Rollout
from .worlds import MetaAgents


class Trainer:
    """The in-process training loop: its worlds, one actor over all their agents, a learner."""

    def __init__(self, cfg: TrainConfig, run_dir: Path, resume: bool = True, log=print):
        self.cfg, self.log = cfg, log
        self.learner = Learner(cfg, run_dir, resume=resume, log=log)
        self.envs = MetaAgents(cfg)
        self.actor = Actor(cfg, self.learner.net, np.arange(self.envs.n_agents))

    # the run's progress, as the learner counts it
    net = property(lambda self: self.learner.net)
    episode = property(lambda self: self.learner.episode)
    updates = property(lambda self: self.learner.updates)
    env_steps = property(lambda self: self.learner.env_steps)

    def run_episode_set(self) -> dict[str, float]:
        """Every meta-agent world plays one episode; the learner updates every rollout chunk."""
        cfg, envs, actor, learner = self.cfg, self.envs, self.actor, self.learner
        started, cpu_started, episode = time.time(), time.process_time(), learner.episode
        schedule = learner.schedule.episode
        stats: dict[str, list[float]] = {}

        def learn(rollout: Rollout, env_steps: int) -> None:
            for key, value in learner.learn(rollout, env_steps).items():
                stats.setdefault(key, []).append(value)
            actor.weights_version = learner.version

        food = play_episode_set(cfg, envs, actor, episode, learn, schedule)
        result = {key: float(np.mean(values)) for key, values in stats.items()}
        result["food_mean"] = float(food.mean())
        result |= {f"food_env{i}": float(f) for i, f in enumerate(food)}
        result |= {"valid_rate": float(np.mean(actor.valid_rate)), "highway_intensity": envs.highway,
                   "deposit_strength": envs.deposit, "filter_probability": filter_probability(cfg, schedule),
                   "schedule_episode": schedule}
        learner.end_episodes(len(envs.worlds), result, seconds=time.time() - started,
                             cpu_seconds=time.process_time() - cpu_started)
        return result

    @property
    def ended(self) -> bool:
        """Whether the run is over: ``total_episodes`` played, or the schedule clock at ``schedule_end``."""
        cfg, learner = self.cfg, self.learner
        return learner.episode >= cfg.total_episodes or (
            cfg.schedule_end is not None and learner.schedule.episode >= cfg.schedule_end)

    def train(self, episodes: int | None = None, minutes: float | None = None) -> None:
        """Train until the run has ended, or for ``episodes`` more or ``minutes``, whichever comes
        first. A stop signal (Ctrl-C, SIGTERM, SIGHUP) ends it after the episode set in progress,
        its checkpoint saved, with KeyboardInterrupt: nothing is lost, and the run resumes as if
        never stopped; a second stop interrupts at once (back to the last checkpoint)."""
        learner = self.learner
        target = self.cfg.total_episodes if episodes is None else learner.episode + episodes
        deadline = None if minutes is None else time.time() + 60 * minutes
        stop = StopBetweenSteps(f"stop requested: the episode set in progress ends, then {learner.run_dir / 'latest.pt'} "
                                "is saved (stop again to quit at once, back to the last checkpoint)")
        with handling(STOP_SIGNALS, stop):
            while (learner.episode < target and not self.ended and not stop.requested
                   and (deadline is None or time.time() < deadline)):
                self.log(self.progress_line(self.run_episode_set()))
            self.close()
        if stop.requested:
            self.log(f"stopped at episode {learner.episode}, its checkpoint saved")
            raise KeyboardInterrupt("stopped between episode sets")

    def progress_line(self, stats: dict[str, float]) -> str:
        """The log line of an episode set: food per world, losses, the update's size, speed."""
        learner = self.learner
        sps = learner.env_steps / max(learner.seconds, 1e-9)
        per_env = " ".join(f"{stats[f'food_env{i}']:.0f}" for i in range(len(self.cfg.teams)))
        held = " held" if learner.schedule.held else ""
        clock = f" sched {stats['schedule_episode']:.0f}{held}" if self.cfg.anneal_hold is not None else ""
        imitation = (f"imit {stats['imitation']:.3f} agree {stats['expert_agreement']:.2f} | "
                     if "imitation" in stats else "")
        return (
            f"ep {learner.episode:6d} | food {stats['food_mean']:6.1f} ({per_env}) | "
            f"loss {stats['loss']:.3f} pi {stats['policy']:.3f} v {stats['value']:.3f} "
            f"ent {stats['entropy']:.3f} valid {stats['valid_accuracy']:.3f} act-ok {stats['valid_rate']:.2f} | "
            f"kl {stats['approx_kl']:.4f} upd {stats['update_fraction']:.2f} | "
            f"{imitation}I_h {stats['highway_intensity']:.2f}{clock} | {sps:,.0f} agent-steps/s | "
            f"{learner.seconds / 60:.1f} min ({learner.cpu_seconds / 60:.1f} CPU)"
        )

    def close(self) -> None:
        self.learner.close()


def play_episode_set(cfg: TrainConfig, envs: MetaAgents, actor: Actor, episode: int,
                     on_rollout: Callable[[Rollout, int], None], schedule: int | None = None) -> np.ndarray:
    """Every world plays episode ``episode`` (the filter's and highways' schedules read
    ``schedule``, default ``episode``); each rollout goes to ``on_rollout`` with the agent-steps
    it stands for. Returns the food each world deposited."""
    envs.reset(episode, schedule)
    actor.start_episode(episode, schedule)
    food = np.zeros(len(envs.worlds))
    food_before = 0.0  # at the chunk's start
    frame = envs.observe()
    for step in range(cfg.episode_steps):
        actions = actor.act(frame)
        if cfg.imitate is not None:
            actor.demonstrate(*envs.demonstrations())
        food += envs.step(actions)
        frame = envs.observe()
        actor.reward(frame.rewards)
        done = step + 1 == cfg.episode_steps
        if len(actor) == cfg.rollout_steps or done:
            env_steps = len(actor) * envs.n_agents
            on_rollout(actor.rollout(frame, done, food.sum() - food_before), env_steps)
            food_before = food.sum()
    return food


def export_model(checkpoint: Path, out: Path) -> None:
    """A small shipped model: weights and configuration only (no optimiser state)."""
    net, payload = load_network(checkpoint)
    save_checkpoint(out, net, train_config=payload.get("train_config", {}), progress=payload.get("progress", {}))
