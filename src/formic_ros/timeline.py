"""Where a lockstep step's time goes, across the run's processes.

With ``FORMIC_TIMELINE=DIR`` in the environment (``formic run --timeline DIR`` sets it for its
children) the world node and each agent host note when a step's observations leave and arrive
and when its actions are chosen, leave and arrive (``time.monotonic_ns``: one clock for every
process on the machine), and write the marks to ``DIR/world-PID.csv`` and ``DIR/host-PID.csv``
when their node closes. :func:`segments` lines the files up by step and splits each step's
round trip into consecutive segments that add up to the step (``formic timeline DIR``). Off
(the default), marking is a call to a function that does nothing. Marks are keyed by step: of a
world that played several episodes (reset through its control services), the last one counts.
"""

from __future__ import annotations

import csv
import os
import time
from pathlib import Path

import numpy as np

ENV = "FORMIC_TIMELINE"

# A step's marks in the order its round trip passes them: (process, event, what the segment
# that ends at the event holds). The first segment starts at the step's ``observe``, the last
# ends at the next step's.
PATH = (
    ("world", "sent", "world: encode and publish the observations"),
    ("host", "all_in", "host: take the observations (after the world's last publish)"),
    ("host", "decide", "host: decode them"),
    ("host", "decided", "host: the policies decide"),
    ("host", "answered", "host: publish the actions"),
    ("world", "heard", "world: take the actions (after the host's last publish)"),
    ("world", "stepped", "world: the core steps"),
)
LAST_SEGMENT = "world: bookkeeping, the next observations built"


class Timeline:
    """The marks of one process (``role``: ``world`` or ``host``), kept while ``FORMIC_TIMELINE``
    names a folder."""

    def __init__(self, role: str):
        self.role = role
        folder = os.environ.get(ENV, "")
        self.folder = Path(folder) if folder else None
        self.marks: list[tuple[str, int, int]] = []
        if self.folder is None:
            self.mark = _ignore

    def mark(self, event: str, step: int) -> None:
        self.marks.append((event, step, time.monotonic_ns()))

    def save(self) -> Path | None:
        """Write the marks (once; later calls write nothing)."""
        if self.folder is None or not self.marks:
            return None
        self.folder.mkdir(parents=True, exist_ok=True)
        path = self.folder / f"{self.role}-{os.getpid()}.csv"
        with path.open("w", newline="") as f:
            writer = csv.writer(f)
            writer.writerow(("event", "step", "ns"))
            writer.writerows(self.marks)
        self.marks = []
        return path


def _ignore(event: str, step: int) -> None:
    pass


def _read(path: Path) -> dict[str, dict[int, int]]:
    """event -> step -> ns (the last mark of a step wins: a re-sent step's answer is later)."""
    marks: dict[str, dict[int, int]] = {}
    with path.open(newline="") as f:
        rows = csv.reader(f)
        if next(rows, None) != ["event", "step", "ns"]:
            raise ValueError(f"{path} is not a timeline file (header event,step,ns)")
        for event, step, ns in rows:
            marks.setdefault(event, {})[int(step)] = int(ns)
    return marks


def segments(folder: str | Path) -> dict:
    """The median of each segment of a step's round trip over the steps every process marked
    (step 0, which waits for the agents, and the last step left out), in ms, with the steps
    counted and the median cycle. The host on a step's path is the one that answered last."""
    folder = Path(folder)
    worlds, hosts = sorted(folder.glob("world-*.csv")), sorted(folder.glob("host-*.csv"))
    if len(worlds) != 1 or not hosts:
        raise ValueError(f"{folder} holds {len(worlds)} world and {len(hosts)} host timelines: it needs one world's "
                         f"and its hosts' (run `formic run --timeline DIR` with a fresh DIR)")
    world, host_marks = _read(worlds[0]), [_read(p) for p in hosts]
    observe = world.get("observe", {})
    steps = sorted(s for s in observe if s > 0 and s + 1 in observe
                   and all(s in world.get(e, {}) for p, e, _ in PATH if p == "world")
                   and any(all(s in h.get(e, {}) for p, e, _ in PATH if p == "host") for h in host_marks))
    if not steps:
        raise ValueError(f"{folder}: no step has every mark (was the run shorter than 3 steps?)")
    rows = []
    for s in steps:
        hosts_in = [h for h in host_marks if all(s in h.get(e, {}) for p, e, _ in PATH if p == "host")]
        last = max(hosts_in, key=lambda h: h["answered"][s])
        at = [observe[s], *((world if p == "world" else last)[e][s] for p, e, _ in PATH), observe[s + 1]]
        rows.append(np.diff(at))
    ms = np.median(np.array(rows), axis=0) / 1e6
    labels = [label for _, _, label in PATH] + [LAST_SEGMENT]
    cycle = float(np.median([observe[s + 1] - observe[s] for s in steps])) / 1e6
    return {"steps": len(steps), "hosts": len(host_marks), "cycle_ms": cycle,
            "segments_ms": dict(zip(labels, (float(x) for x in ms)))}
