"""Keep freed heap memory in the process instead of handing it back to the system at once.

glibc returns the top of its heap to the system as soon as more than ``M_TRIM_THRESHOLD`` of it is
free (a few MiB under its default dynamic rule), and serves blocks above ``M_MMAP_THRESHOLD`` with
fresh mappings. The environment frees and allocates a few MiB per step (observations, FFT buffers)
and ~100 MiB at once when synchronous episodes all reset, so under the defaults every step pays
first-touch page faults on memory it just gave back: ~60 per env step with 16 envs, ~0.1 ms of CPU
per env step (docs/simulator.md). Fixed thresholds also switch off glibc's dynamic rule.
"""

from __future__ import annotations

import ctypes
import ctypes.util
from functools import lru_cache

_M_TRIM_THRESHOLD = -1   # mallopt parameter numbers of glibc's malloc.h
_M_MMAP_THRESHOLD = -3
TRIM_THRESHOLD = 128 * 2**20   # free heap kept before any is given back: above one reset's worth
MMAP_THRESHOLD = 16 * 2**20    # blocks from the heap up to this size (observations of 16+ envs)


@lru_cache(maxsize=1)
def retain_freed_memory() -> bool:
    """Set glibc's trim and mmap thresholds for this process (once); False where malloc is not
    glibc's (nothing is changed there)."""
    name = ctypes.util.find_library("c")
    try:
        mallopt = ctypes.CDLL(name).mallopt
    except (OSError, AttributeError, TypeError):
        return False
    mallopt.argtypes, mallopt.restype = (ctypes.c_int, ctypes.c_int), ctypes.c_int
    return bool(mallopt(_M_TRIM_THRESHOLD, TRIM_THRESHOLD)) and bool(mallopt(_M_MMAP_THRESHOLD, MMAP_THRESHOLD))
