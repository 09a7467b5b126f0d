"""Running the episodes: a process pool, a progress bar, and a crash-safe log to resume from.

Each finished episode is one JSON line appended to ``episodes.jsonl`` by the parent process
alone (flushed and fsynced), so an interrupted run loses at most the episodes in flight; a
torn last line (killed mid-write) is cut off on the next start and that episode is redone.
A finished evaluation's log is sealed into ``episodes.jsonl.gz`` (:meth:`EpisodeLog.seal`), the
compact form the repository keeps; episodes run later go to a plain ``episodes.jsonl`` beside it.
"""

from __future__ import annotations

import dataclasses
import functools
import gzip
import json
import os
import signal
import sys
import time
import traceback
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from multiprocessing import get_context
from pathlib import Path

import numpy as np

from formic_runtime.memory import keep_freed_memory
from formic_runtime.threads import configure_threads

from .matrix import PolicyOptions, Setting, StoredScenario, Task, plan_tasks


class EpisodeError(RuntimeError):
    """An episode raised; names the algorithm and scenario file."""


LOG_NAME = "episodes.jsonl"
SEALED_SUFFIX = ".gz"
SEAL_LEVEL = 9  # fixed, so the same episodes always seal to the same bytes


class EpisodeLog:
    """The record of finished episodes, keyed by :attr:`Task.key`: the sealed part (``PATH.gz``,
    read-only) and the plain append-only tail (``PATH``); a tail record replaces a sealed one of
    the same key."""

    def __init__(self, path: Path):
        self.path = Path(path)
        self.sealed_path = self.path.with_name(self.path.name + SEALED_SUFFIX)
        self.skipped_lines = 0
        self.repaired = False
        self._handle = None

    @property
    def sealed(self) -> bool:
        """The evaluation has ended: its episodes sealed, no plain tail still being written."""
        return self.sealed_path.is_file() and not self.path.exists()

    def load(self) -> dict[str, dict]:
        """Finished episodes, sealed ones first in their sealed order, then the tail's in its
        order; cuts off a torn last line of the tail and skips unreadable lines."""
        records: dict[str, dict] = {}
        if self.sealed_path.exists():
            self._read_lines(gzip.decompress(self.sealed_path.read_bytes()), records)
        if self.path.exists():
            data = self.path.read_bytes()
            end = data.rfind(b"\n") + 1
            if end < len(data):
                with open(self.path, "r+b") as handle:
                    handle.truncate(end)
                    handle.flush()
                    os.fsync(handle.fileno())
                self.repaired = True
            self._read_lines(data[:end], records)
        return records

    def _read_lines(self, data: bytes, records: dict[str, dict]) -> None:
        for line in data.splitlines():
            if not line.strip():
                continue
            try:
                record = json.loads(line)
                records[record["key"]] = record
            except (ValueError, KeyError, TypeError):
                self.skipped_lines += 1

    def seal(self) -> Path:
        """Fold every finished episode into the sealed file and delete the plain tail.

        The records keep :meth:`load`'s order (what reports resample or sum in record order
        comes out the same), one compact JSON line each as :meth:`append` writes them, gzipped at
        :data:`SEAL_LEVEL` with mtime 0: the same episodes seal to the same bytes, and a log
        that was never resumed unpacks to exactly its plain file. Refuses a log with unreadable
        lines (they would be lost)."""
        self.close()
        records = self.load()
        if self.skipped_lines:
            raise ValueError(f"{self.path}: {self.skipped_lines} unreadable line(s); not sealed")
        if not records:
            raise ValueError(f"{self.path}: no episodes to seal")
        text = "".join(json.dumps(record, separators=(",", ":")) + "\n" for record in records.values())
        partial = self.sealed_path.with_name(self.sealed_path.name + ".partial")
        with open(partial, "wb") as handle:
            handle.write(gzip.compress(text.encode(), compresslevel=SEAL_LEVEL, mtime=0))
            handle.flush()
            os.fsync(handle.fileno())
        os.replace(partial, self.sealed_path)
        self.path.unlink(missing_ok=True)
        return self.sealed_path

    def append(self, record: dict) -> None:
        if self._handle is None:
            self.path.parent.mkdir(parents=True, exist_ok=True)
            self._handle = open(self.path, "ab")
        self._handle.write((json.dumps(record, separators=(",", ":")) + "\n").encode())
        self._handle.flush()
        os.fsync(self._handle.fileno())

    def close(self) -> None:
        if self._handle is not None:
            self._handle.close()
            self._handle = None


def folder_log(folder: str | Path) -> EpisodeLog:
    """The episode log of an evaluation folder (sealed, plain, both or not yet started)."""
    return EpisodeLog(Path(folder) / LOG_NAME)


def folder_episodes(folder: str | Path) -> list[dict]:
    """Every finished episode of an evaluation folder ([] when it has none yet): the one way
    reports and tables read episodes, sealed or not."""
    return list(folder_log(folder).load().values())


@functools.cache
def _learned_policy(model: str | None, model_digest: str, greedy: bool):
    """The learned policy of a worker, loaded once per model: loading a checkpoint is the costly
    part, and reset() clears the LSTM state per episode."""
    from formic_runtime.registry import make_policy

    return make_policy("formic", model=model, greedy=greedy)


def run_task(task: Task) -> dict:
    """Run one episode and return its log record (runs in a worker process)."""
    from formic_runtime.episode import run_episode
    from formic_runtime.registry import apply_world_overrides, make_policy, world_overrides
    from formic_runtime.team import Team
    from formic_world import Scenario

    from .probes import with_channel_empty

    stored = task.scenario
    setting = stored.setting
    try:
        scenario = Scenario.load(stored.path)
        if task.no_pheromones:
            scenario = with_channel_empty(scenario)
        if task.pheromone_variant != "standard":
            scenario = dataclasses.replace(scenario, config=scenario.config.replace(
                pheromone_variant=task.pheromone_variant))
        # The stored layout, in the world this algorithm runs in (one-slot queues for csaf-ref).
        scenario = apply_world_overrides(scenario, [task.algorithm])
        if task.algorithm == "formic":
            policy = _learned_policy(task.model, task.model_digest, task.greedy)
            # the same layout, observed through the window the model was trained on (Table III)
            if policy.view_size != scenario.config.view_size:
                scenario = dataclasses.replace(scenario, config=scenario.config.replace(view_size=policy.view_size))
        else:
            policy = make_policy(task.algorithm)
        start = time.perf_counter()
        team = Team(((task.algorithm, tuple(range(scenario.config.n_agents))),))
        team.members = [(policy, np.arange(scenario.config.n_agents))]
        result = run_episode(scenario, team, steps=setting.steps)
        wall = time.perf_counter() - start
    except Exception as exc:
        frame = traceback.extract_tb(exc.__traceback__)[-1]
        raise EpisodeError(
            f"{task.algorithm} on {stored.path.name}: {type(exc).__name__}: {exc} "
            f"(at {frame.filename}:{frame.lineno} in {frame.name})"
        ) from exc
    record = {
        "key": task.key,
        "algorithm": task.algorithm,
        "variant": task.variant,
        "model": task.model_digest,
        **dataclasses.asdict(setting),  # size, agents, obstacles, env, steps
        "seed": stored.seed,
        "scenario": stored.path.name,
        "scenario_digest": stored.digest,
        "food": float(result.food),
        "step_ms_mean": float(result.decision_seconds.mean() * 1e3),
        "world_step_ms_mean": float(result.step_seconds.mean() * 1e3),
        "wall_s": round(wall, 4),
        "food_curve": [round(float(v), 4) for v in result.food_curve],
    }
    overrides = world_overrides([task.algorithm])
    if overrides:
        record["world_overrides"] = overrides
    return record


def _init_worker(threads: int) -> None:
    # Ctrl-C goes to the whole process group: let the parent alone handle it.
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    configure_threads(threads)
    keep_freed_memory()  # a spawned worker does not run the `formic` command's setup


@dataclass
class RunStats:
    computed: int = 0
    reused: int = 0
    interrupted: bool = False
    wall_s: float = 0.0


def run_tasks(
    tasks: list[Task],
    log: EpisodeLog,
    done: dict[str, dict],
    workers: int = 2,
    progress: bool | None = None,
    on_record: Callable[[dict], None] | None = None,
) -> RunStats:
    """Run the tasks not yet in ``done`` (which gains the new records); a stop signal (Ctrl-C,
    SIGTERM, SIGHUP: :mod:`formic_runtime.signals`) stops cleanly: the workers are ended before
    they can write into a closed pipe, the finished episodes are kept, later signals wait.

    ``progress=None`` shows the bar only on a terminal.
    """
    from tqdm import tqdm

    from formic_runtime.signals import FirstStopInterrupts, handling

    pending = [t for t in tasks if t.key not in done]
    stats = RunStats(reused=len(tasks) - len(pending))
    timed_with = worker_count(workers, len(pending))
    start = time.perf_counter()
    disable = None if progress is None else not progress
    bar = tqdm(total=len(pending), desc="formic eval", unit="episode", file=sys.stderr, disable=disable,
               dynamic_ncols=True)
    results = _results(pending, workers)
    stop_rule = FirstStopInterrupts()
    # SIGINT keeps Python's handler (or the SIG_IGN a background job inherits, as the shell means)
    with handling((signal.SIGTERM, signal.SIGHUP), stop_rule):
        try:
            for record in results:
                record["workers"] = timed_with  # the processes that shared the cores while its times were measured
                log.append(record)
                done[record["key"]] = record
                stats.computed += 1
                where = f"{record['algorithm']} {record['size']}/{record['agents']}/{record['env']}"
                bar.set_postfix_str(where, refresh=False)
                bar.update()
                if on_record is not None:
                    on_record(record)
        except KeyboardInterrupt:
            stats.interrupted = True
        finally:
            stop_rule.stop()  # a second signal now would cut the workers' end short
            results.close()
            bar.close()
            log.close()
            stats.wall_s = time.perf_counter() - start
    return stats


def worker_count(workers: int, pending: int) -> int:
    """The processes that run ``pending`` episodes when ``workers`` are asked for (1: in this process)."""
    return 1 if workers <= 1 or pending <= 1 else min(workers, pending)


def _results(pending: list[Task], workers: int) -> Iterator[dict]:
    workers = worker_count(workers, len(pending))
    if workers == 1:
        configure_threads()
        for task in pending:
            yield run_task(task)
        return
    threads = max(1, (os.cpu_count() or 1) // workers)
    pool = get_context("spawn").Pool(workers, initializer=_init_worker, initargs=(threads,))
    try:
        yield from pool.imap_unordered(run_task, pending, chunksize=1)
        pool.close()
    finally:
        pool.terminate()
        pool.join()


def evaluate(
    matrix: dict[Setting, list[StoredScenario]],
    algorithms: list[str],
    options: PolicyOptions,
    out: Path,
    workers: int = 2,
    progress: bool | None = None,
    source: str = "",
) -> dict:
    """Run (or resume) every episode of the matrix, then write the results, figures and report.
    The run holds ``out`` (:func:`~formic_world.files.held_directory`): a second evaluation into
    the same folder fails at once instead of appending the same episodes twice.

    Returns the summary that ``formic eval --json`` prints (:func:`write_report`).
    """
    from formic_world.files import held_directory

    from .results import aggregate

    out = Path(out)
    tasks = plan_tasks(matrix, algorithms, options)
    with held_directory(out):
        log = folder_log(out)
        done = log.load()
        stats = run_tasks(tasks, log, done, workers=workers, progress=progress)
        records = [done[t.key] for t in tasks if t.key in done]
        cells = aggregate(records)
        run = {
            "algorithms": algorithms,
            "scenarios": source,
            "settings": len(matrix),
            "episodes": {"total": len(tasks), "done": len(records), "computed": stats.computed, "reused": stats.reused},
            "interrupted": stats.interrupted,
            "workers": workers,
            "episode_workers": workers_of(records),
            "model": options.model,
            "model_digest": options.model_digest,
            "greedy": options.greedy,
            "no_pheromones": options.no_pheromones,
            "pheromone_variant": options.pheromone_variant,
            "wall_s": round(stats.wall_s, 3),
            "log": {"path": str(log.path), "torn_line_removed": log.repaired, "unreadable_lines": log.skipped_lines},
        }
        return write_report(out, records, cells, run, {"episodes_jsonl": str(log.path), "scenarios": source})


def write_report(out: Path, records: list[dict], cells: list[dict], run: dict,
                 files: dict | None = None) -> dict:
    """Results (CSV/JSON), figures and results.md for these cells (none without cells). Returns
    the summary ``formic eval --json`` prints: the run, its cells without their curves, and
    ``files`` with the files written here."""
    from .paper import markdown_report
    from .plots import plot_all
    from .results import public_cell, write_results

    files = dict(files or {})
    if cells:
        files |= write_results(out, records, cells, run)
        files["figures"] = plot_all(cells, out)
        report = out / "results.md"
        report.write_text(markdown_report(cells, run))
        files["report"] = str(report)
    return {"out": str(out)} | run | {"cells": [public_cell(c) for c in cells], "files": files}


def workers_of(records: list[dict]) -> str:
    """How many worker processes shared the cores while these episodes' decision times were
    measured (each record keeps its own; a reused episode was timed by the call that ran it)."""
    counts = sorted({r["workers"] for r in records if "workers" in r})
    unrecorded = any("workers" not in r for r in records)  # logged before records kept the count
    return " or ".join([*map(str, counts), *(["an unrecorded number of"] if unrecorded else [])])


def report_everything(out: Path) -> dict:
    """Rebuild the results from every episode logged in OUT (several calls with different
    algorithms or settings into one directory end up in one report); runs nothing."""
    from .results import aggregate

    out = Path(out)
    log = folder_log(out)
    records = list(log.load().values())
    cells = aggregate(records)
    run = {"algorithms": sorted({r["algorithm"] for r in records}), "scenarios": str(out / "scenarios"),
           "episodes": {"total": len(records), "done": len(records), "computed": 0, "reused": len(records)},
           "episode_workers": workers_of(records), "report_only": True}
    return write_report(out, records, cells, run)
