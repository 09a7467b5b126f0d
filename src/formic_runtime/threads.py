"""The thread settings of a process that runs policies.

torch's intra-op pool defaults to one OpenMP thread per core, and OpenMP workers spin for a
while after each parallel region: beside the (single-threaded) numba world step, the DDS
threads and other processes they take the cores the next step needs. A team's batch is small,
so one thread is the fast setting. ``formic bench decide`` on a busy 2-core machine, 16/32/64/128
agents: 436/364/165/195 ms of decisions a step with torch's default pool, 9.5/12/20/35 ms with
one thread."""

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
