"""The learner: network, optimiser, counters (the weights version is the updates so far),
its own random stream per update (minibatch permutations), the optional moving average of the weights
(``weight_average``), the fall guard (``guard_drop``: ``best.pt`` and rollbacks to it), checkpoints, resume
and the TensorBoard log.
:meth:`Learner.learn` makes one update from an actor's rollout. ``formic train`` and the ROS
trainer node (``formic train-ros``) both drive it."""

from __future__ import annotations

import copy
import json
from collections.abc import Callable
from pathlib import Path

import numpy as np
import torch

from formic_agent.checkpoint import (CheckpointError, initialise_from, load_network, read_checkpoint, save_checkpoint,
                                     write_checkpoint)

from .algorithm import check_update_precision, make_optimizer, set_learning_rate, training_network, update
from .config import TrainConfig, off_as_none, plain
from .guard import BEST, ROLL_BACK, WATCH, FallGuard, Verdict
from .rollout import Rollout
from .schedule import ScheduleClock

# settings a run may change when it resumes (where it stops, how fast, where it started from)
RESUMABLE = frozenset({"total_episodes", "schedule_end", "threads", "checkpoint_every", "init_weights",
                       "weight_average"})
# the counters a checkpoint carries; "seconds" is the learner's wall clock, "cpu_seconds" this
# process's CPU time over the same spans (what a CPU-hour budget counts: pauses and a busy
# machine do not inflate it). Checkpoints from before cpu_seconds existed resume with their wall
# seconds in its place, an upper bound.
PROGRESS = ("episode", "updates", "env_steps", "seconds", "cpu_seconds")


def learner_stream(cfg: TrainConfig, updates: int) -> np.random.Generator:
    """The learner's random stream (minibatch permutations) for the update made after ``updates`` updates."""
    return np.random.default_rng([cfg.seed, 5, int(updates)])


class Learner:
    def __init__(self, cfg: TrainConfig, run_dir: Path, resume: bool = True, log: Callable[[str], None] = print):
        check_update_precision(cfg)
        self.cfg = cfg
        self.run_dir = Path(run_dir)
        self.run_dir.mkdir(parents=True, exist_ok=True)
        self.log = log
        torch.set_num_threads(cfg.threads)
        torch.manual_seed(cfg.seed)
        self.net = training_network(cfg)
        self.optimizer = make_optimizer(self.net, cfg)
        self.episode = 0  # global environment episodes finished
        self.episode_sets = 0  # ends of episodes (sets) reported in this process
        self.updates = 0
        self.env_steps = 0
        self.seconds = 0.0
        self.cpu_seconds = 0.0
        self.averaged = None  # the moving average of the weights (a network), with a weight_average
        self.guard = FallGuard.from_config(cfg)  # None without a guard_drop
        self.schedule = ScheduleClock.from_config(cfg)  # the episode the filter's and highways' schedules read
        latest = self.run_dir / "latest.pt"
        stored_average = None
        if resume and latest.exists():
            stored_average = self._resume(latest)
        elif cfg.init_weights is not None:
            net, _ = load_network(cfg.init_weights)
            initialise_from(self.net, net)
            self.log(f"network initialised from {cfg.init_weights}")
        if cfg.weight_average is not None:  # the average starts at the weights, unless the checkpoint carries one
            self.averaged = copy.deepcopy(self.net).requires_grad_(False)
            if stored_average is not None:
                self.averaged.load_state_dict(stored_average)
        config_text = json.dumps(cfg.to_dict(), indent=2)
        (self.run_dir / "config.json").write_text(config_text)
        from torch.utils.tensorboard import SummaryWriter

        self.writer = SummaryWriter(str(self.run_dir / "tb"))
        self.writer.add_text("config", config_text)

    @property
    def version(self) -> int:
        """The weights version: updates made so far."""
        return self.updates

    def _resume(self, path: Path) -> dict | None:
        """Weights, optimiser and counters from ``path``; returns the weight average it carries."""
        payload = read_checkpoint(path)
        stored = off_as_none(payload.get("train_config", {}))  # written before None meant off: 0 or ""
        changed = sorted(k for k, v in self.cfg.to_dict().items()
                         if k not in RESUMABLE and k in stored and plain(stored[k]) != plain(v))
        if changed:
            raise CheckpointError(
                f"{path} was trained with different settings ({', '.join(changed)}); "
                "use the same settings, a new --run-dir, or --fresh"
            )
        if "optimizer" not in payload:
            raise CheckpointError(f"{path} holds no optimiser state (a finished recipe stage's): its training is over; "
                                  "start a new --run-dir from its weights (init_weights) instead")
        self.net.load_state_dict(payload["state_dict"])
        self.optimizer.load_state_dict(payload["optimizer"])
        progress = {"cpu_seconds": payload["progress"]["seconds"]} | payload["progress"]
        for key in PROGRESS:
            setattr(self, key, progress[key])
        if self.guard is not None and "guard" in progress:
            self.guard.load(progress["guard"])
        if "schedule" in progress:
            self.schedule.load(progress["schedule"])
        else:  # a checkpoint from before the schedule clock: it read the episode count
            self.schedule.episode = self.episode
        self.log(f"resumed from {path}: episode {self.episode}, update {self.updates}")
        return payload.get("averaged_state_dict")

    def learn(self, rollout: Rollout, env_steps: int | None = None) -> dict[str, float]:
        """One update from one rollout; ``env_steps``: the agent-steps it stands for (default:
        its learning agents')."""
        set_learning_rate(self.optimizer, self.cfg, self.updates, 1.0 if self.guard is None else self.guard.lr_factor)
        rng = learner_stream(self.cfg, self.updates)  # per update: a resumed run permutes as an uninterrupted one
        stats = update(self.net, self.optimizer, self.cfg, rollout, rng)
        if self.averaged is not None:
            with torch.no_grad():
                weights = self.net.state_dict()
                for name, value in self.averaged.state_dict().items():
                    if value.is_floating_point():
                        value.lerp_(weights[name], 1.0 - self.cfg.weight_average)
                    else:
                        value.copy_(weights[name])
        self.updates += 1
        self.env_steps += int(rollout.actions.size if env_steps is None else env_steps)
        return stats

    def end_episodes(self, episodes: int, stats: dict[str, float], seconds: float = 0.0,
                     cpu_seconds: float = 0.0) -> None:
        """``episodes`` environment episodes have ended (one episode set), taking ``seconds`` of
        wall clock and ``cpu_seconds`` of CPU: their statistics go to the log under ``train/``,
        the schedule clock and the fall guard see their ``food_mean``, and the checkpoint is written every
        ``checkpoint_every`` and after each step the guard takes (so that no rollback lies between
        the last checkpoint and a best.pt newer than it: a resumed run rewrites that best.pt as it was)."""
        self.episode += episodes
        self.episode_sets += 1
        self.seconds += seconds
        self.cpu_seconds += cpu_seconds
        self.record("train", stats, self.episode)
        if self.seconds > 0:
            self.writer.add_scalar("train/agent_steps_per_s", self.env_steps / self.seconds, self.episode)
        self.writer.flush()
        played_at = self.schedule.episode
        self.schedule.observe(episodes, stats.get("food_mean"))
        verdict = (Verdict(WATCH) if self.guard is None
                   else self.guard.observe(self.episode, stats["food_mean"], schedule=played_at + episodes))
        if verdict.action == BEST:
            self.save("best.pt")
        if verdict.line:
            self.log(verdict.line)
        if verdict.action == ROLL_BACK:
            self.roll_back()
        if verdict.action != WATCH or self.episode_sets % self.cfg.checkpoint_every == 0:
            self.save()

    def roll_back(self) -> None:
        """The weights of ``best.pt`` with a fresh optimiser (the guard lowers the learning rate),
        and the schedule clock where it stood with them."""
        best = read_checkpoint(self.run_dir / "best.pt")
        self.net.load_state_dict(best["state_dict"])
        self.schedule.roll_back(best["progress"].get("schedule", {"episode": best["progress"]["episode"]}))
        self.optimizer = make_optimizer(self.net, self.cfg)
        set_learning_rate(self.optimizer, self.cfg, self.updates, self.guard.lr_factor)

    def record(self, prefix: str, stats: dict[str, float], step: int) -> None:
        for key, value in stats.items():
            self.writer.add_scalar(f"{prefix}/{key}", value, step)

    def save(self, name: str = "latest.pt") -> None:
        """The training state as ``name`` (with the guard's state); with a weight average also
        ``averaged.pt``, written after ``latest.pt`` (which carries the average too, so a crash
        between the two loses nothing). ``best.pt`` leaves out the optimiser's state (two thirds
        of the file): a rollback starts a fresh optimiser and a warm start takes the weights alone."""
        progress = {key: getattr(self, key) for key in PROGRESS}
        progress["schedule"] = self.schedule.state()
        if self.guard is not None:
            progress["guard"] = self.guard.state()
        averaged = {} if self.averaged is None else {"averaged_state_dict": self.averaged.state_dict()}
        optimizer = {"optimizer": self.optimizer.state_dict()} if name == "latest.pt" else {}
        save_checkpoint(self.run_dir / name, self.net, train_config=self.cfg.to_dict(), progress=progress,
                        **optimizer, **averaged)
        if self.averaged is not None and name == "latest.pt":
            save_checkpoint(self.run_dir / "averaged.pt", self.averaged, progress=progress,
                            weight_average=self.cfg.weight_average)

    def close(self) -> None:
        self.save()
        self.writer.close()


def drop_optimizer_state(path: Path) -> None:
    """Rewrite a training checkpoint whose training is over without its optimiser's state (two
    thirds of the file); one without it is left as it is."""
    payload = read_checkpoint(path)
    if "optimizer" in payload:
        del payload["optimizer"]
        write_checkpoint(path, payload)
