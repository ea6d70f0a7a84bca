"""Keep large freed blocks in the process's heap (glibc), so big temporaries are reused instead of
mapped afresh: the PPO update's tensors, and the nodes' message buffers.

glibc serves a block above its mmap threshold (adapting up to 32 MiB) with a fresh ``mmap`` and returns
it to the kernel on ``free``; the next allocation of that size then faults in and zero-fills every
page again. A PPO update allocates and frees tensors of 5-42 MB many times (320-sample activations,
their gradients, the stacked rollout): without this, a benchmark run spent ~35% more page faults and
~0.4 ms of system time per env step on it (docs/design/policies.md, Speed). Raising the mmap and trim
thresholds keeps those blocks in the heap for the next update; the peak resident size stays the same.
The pipeline's messages are 64-200 KiB, just above the initial 128 KiB threshold: a node receiving a
188 KiB message spends ~40% less CPU on it with this (``scripts/bench/ros_messages.py``).

Process-wide, like ``torch.set_num_threads``; a no-op (returns False) where the C library has no
``mallopt`` (not glibc).
"""

from __future__ import annotations

import ctypes

M_TRIM_THRESHOLD, M_MMAP_THRESHOLD = -1, -3  # malloc.h
KEEP_BYTES = 1 << 30


def keep_freed_blocks(limit: int = KEEP_BYTES) -> bool:
    """Serve blocks up to ``limit`` bytes (a C int) from the heap and keep up to ``limit`` freed at its top."""
    try:
        mallopt = ctypes.CDLL(None).mallopt
    except (OSError, AttributeError):
        return False
    mallopt.argtypes, mallopt.restype = (ctypes.c_int, ctypes.c_int), ctypes.c_int
    return bool(mallopt(M_MMAP_THRESHOLD, limit)) and bool(mallopt(M_TRIM_THRESHOLD, limit))
