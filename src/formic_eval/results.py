"""From episode records to cells (one per algorithm and setting), and the CSV/JSON files.

A cell's ``food_std`` is the sample standard deviation over its scenarios (ddof=1; 0 for a
single scenario). Per-step time is the team's decision time (all agents choosing actions,
``EpisodeStats.decision_seconds``), averaged over steps then scenarios; per agent it is that
divided by the team size.
"""

from __future__ import annotations

import csv
import json
from collections.abc import Iterable
from pathlib import Path

import numpy as np

from formic_world.files import atomic_open

from .paper import paper_food

CELL_FIELDS = ("algorithm", "variant", "size", "agents", "obstacles", "env", "steps")
CELL_COLUMNS = CELL_FIELDS + (
    "n", "food_mean", "food_std", "food_min", "food_max", "step_ms_mean", "agent_step_ms_mean",
    "world_step_ms_mean", "food_ratio_to_planner", "paper_food", "paper_ratio_to_planner",
)
EPISODE_COLUMNS = (
    "algorithm", "variant", "model", "size", "agents", "obstacles", "env", "steps", "seed", "scenario",
    "scenario_digest", "food", "step_ms_mean", "agent_step_ms_mean", "world_step_ms_mean", "wall_s",
)


def food_stats(values: Iterable[float]) -> dict[str, float]:
    """Mean, sample std (ddof=1, 0 for one value), min and max."""
    x = np.asarray(list(values), dtype=np.float64)
    if len(x) == 0:
        raise ValueError("no values")
    return {
        "food_mean": float(x.mean()),
        "food_std": float(x.std(ddof=1)) if len(x) > 1 else 0.0,
        "food_min": float(x.min()),
        "food_max": float(x.max()),
    }


def aggregate(records: Iterable[dict]) -> list[dict]:
    """One cell per (algorithm, variant, setting), with curves and the ratio to the planner."""
    groups: dict[tuple, list[dict]] = {}
    for record in records:
        groups.setdefault(tuple(record[f] for f in CELL_FIELDS), []).append(record)
    cells = []
    for key, group in groups.items():
        models = sorted({r.get("model", "") for r in group})
        if len(models) > 1:
            raise ValueError(f"{key[0]} ({key[1] or 'default'}) was run with {len(models)} different models "
                             f"({', '.join(m[:12] for m in models)}): evaluate each model into its own folder")
        group.sort(key=lambda r: (r["seed"], r["scenario"]))
        cell = dict(zip(CELL_FIELDS, key))
        curves = np.array([r["food_curve"] for r in group], dtype=np.float64)
        curve_std = curves.std(axis=0, ddof=1) if len(group) > 1 else np.zeros(curves.shape[1])
        step_ms = float(np.mean([r["step_ms_mean"] for r in group]))
        cell |= {"n": len(group)} | food_stats(r["food"] for r in group)
        cell |= {
            "step_ms_mean": step_ms,
            "agent_step_ms_mean": step_ms / cell["agents"],
            "world_step_ms_mean": float(np.mean([r["world_step_ms_mean"] for r in group])),
            "seeds": [r["seed"] for r in group],
            "food_curve_mean": curves.mean(axis=0).round(4).tolist(),
            "food_curve_std": curve_std.round(4).tolist(),
        }
        cells.append(cell)
    setting = lambda c: tuple(c[f] for f in CELL_FIELDS[2:])  # noqa: E731
    planner = {setting(c): c["food_mean"] for c in cells if c["algorithm"] == "planner"}
    for cell in cells:
        reference = planner.get(setting(cell))
        cell["food_ratio_to_planner"] = cell["food_mean"] / reference if reference else None
        cell["paper_food"] = paper_food(cell)
        planner_paper = paper_food(cell | {"algorithm": "planner", "variant": ""})
        cell["paper_ratio_to_planner"] = (
            cell["paper_food"] / planner_paper if cell["paper_food"] is not None and planner_paper else None
        )
    return sorted(cells, key=cell_order)


def cell_order(cell: dict) -> tuple:
    from .matrix import env_rank

    return (cell["size"], cell["steps"], cell["obstacles"], env_rank(cell["env"]), cell["agents"],
            cell["algorithm"], cell["variant"])


def episode_rows(records: Iterable[dict]) -> list[dict]:
    """Per-scenario rows (no curves) in a stable order."""
    rows = [{c: r[c] for c in EPISODE_COLUMNS if c in r} | {"agent_step_ms_mean": r["step_ms_mean"] / r["agents"]}
            for r in records]
    return sorted(rows, key=lambda r: cell_order(r) + (r["seed"], r["scenario"]))


def public_cell(cell: dict) -> dict:
    """A cell without its per-step curves (what ``--json`` prints)."""
    return {k: v for k, v in cell.items() if not k.startswith("food_curve")}


def write_csv(path: Path, rows: list[dict], columns: Iterable[str]) -> None:
    columns = list(columns)
    with atomic_open(path, newline="") as handle:
        writer = csv.DictWriter(handle, fieldnames=columns, extrasaction="ignore")
        writer.writeheader()
        for row in rows:
            writer.writerow({c: "" if row.get(c) is None else row.get(c) for c in columns})


def write_curves_csv(path: Path, cells: list[dict]) -> None:
    """Food versus time: one row per cell and step (mean and std over scenarios)."""
    with atomic_open(path, newline="") as handle:
        writer = csv.writer(handle)
        writer.writerow(CELL_FIELDS + ("step", "food_mean", "food_std"))
        for cell in cells:
            key = [cell[f] for f in CELL_FIELDS]
            for t, (m, s) in enumerate(zip(cell["food_curve_mean"], cell["food_curve_std"]), start=1):
                writer.writerow(key + [t, m, s])


def write_json(path: Path, obj: dict) -> None:
    with atomic_open(path, newline="") as handle:
        json.dump(obj, handle, indent=1)


def write_results(out: Path, records: list[dict], cells: list[dict], run: dict) -> dict[str, str]:
    """episodes.csv, results.csv, curves.csv and results.json; returns their paths."""
    out = Path(out)
    rows = episode_rows(records)
    files = {
        "episodes_csv": out / "episodes.csv",
        "results_csv": out / "results.csv",
        "curves_csv": out / "curves.csv",
        "results_json": out / "results.json",
    }
    write_csv(files["episodes_csv"], rows, EPISODE_COLUMNS)
    write_csv(files["results_csv"], cells, CELL_COLUMNS)
    write_curves_csv(files["curves_csv"], cells)
    write_json(files["results_json"], {"run": run, "cells": cells, "episodes": rows})
    return {k: str(v) for k, v in files.items()}

