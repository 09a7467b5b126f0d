"""A training run's TensorBoard scalars read back (``Learner`` writes them to ``RUN_DIR/tb``)."""

from __future__ import annotations

from pathlib import Path


def read_scalars(run_dir: Path) -> dict[str, list[tuple[int, float]]]:
    """Every scalar of every event file of a run, by tag, sorted by step (later files win on
    repeated steps: a resumed run logs its last episodes again)."""
    from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

    series: dict[str, dict[int, float]] = {}
    for path in sorted((Path(run_dir) / "tb").glob("events.out.tfevents.*")):
        events = EventAccumulator(str(path))
        events.Reload()
        for tag in events.Tags()["scalars"]:
            series.setdefault(tag, {}).update({e.step: e.value for e in events.Scalars(tag)})
    return {tag: sorted(points.items()) for tag, points in series.items()}
