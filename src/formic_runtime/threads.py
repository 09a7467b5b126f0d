"""The thread settings of a process that runs policies.

torch's intra-op pool defaults to one OpenMP thread per core, and OpenMP workers spin for a
while after each parallel region: beside a single-threaded numba world step and other
processes, those spinning threads take the cores the next step needs. A team's batch is small
(at most a few hundred rows), so one thread is the fast setting (measured: ``formic sim
--agents 128 --policy formic`` on a busy 2-core machine, 221 ms decisions and 104 ms world
steps per step with the default pool, 42 and 4 ms with one thread)."""

from __future__ import annotations

import os
import sys

DEFAULT_THREADS = 1


def configure_threads(threads: int = DEFAULT_THREADS) -> None:
    """Run torch (and any OpenMP/MKL code) on ``threads`` threads in this process and in the
    processes it starts. Call it before running a policy; torch need not be imported yet."""
    for name in ("OMP_NUM_THREADS", "MKL_NUM_THREADS"):
        os.environ[name] = str(threads)
    if "torch" in sys.modules:
        sys.modules["torch"].set_num_threads(threads)
