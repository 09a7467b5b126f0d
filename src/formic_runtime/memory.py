"""How this process's C heap treats freed memory.

By default glibc's malloc hands large freed blocks back to the kernel (blocks over its mmap
threshold are unmapped, and free memory at the heap's top over its trim threshold is trimmed),
and the next allocation of that size faults fresh zeroed pages in again. A policy's forward
pass allocates and frees the same large buffers every step, so it paid that on every call:
128 learned agents on 128x128, 1024 steps (2-core AMD EPYC, paired, the same digest): `formic
sim` 131-138 steps/s with glibc's defaults, 195-218 with this; over ROS (batched) the host's
forward pass 7.1 ms of CPU a step, 4.8-5.0 with it (docs/ros.md, "Speed"). Keeping freed memory costs
nothing but a peak that stays resident. Elsewhere than glibc this does nothing.
"""

from __future__ import annotations

import ctypes
import ctypes.util

M_TRIM_THRESHOLD = -1  # mallopt parameters (malloc.h)
M_MMAP_THRESHOLD = -3
MMAP_THRESHOLD = 32 * 1024 * 1024  # the largest glibc accepts on 64-bit: bigger blocks are still mapped
TRIM_THRESHOLD = 1024 * 1024 * 1024  # free memory at the heap's top kept up to this


def keep_freed_memory() -> bool:
    """Have glibc's malloc keep freed memory for reuse instead of returning it to the kernel
    (fixed thresholds, which also turns off glibc's adjusting them); whether it applied."""
    try:
        libc = ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6")
        mallopt = libc.mallopt
    except (OSError, AttributeError):  # not glibc (musl, macOS): nothing to set
        return False
    mallopt.argtypes, mallopt.restype = [ctypes.c_int, ctypes.c_int], ctypes.c_int
    return bool(mallopt(M_MMAP_THRESHOLD, MMAP_THRESHOLD)) & bool(mallopt(M_TRIM_THRESHOLD, TRIM_THRESHOLD))
