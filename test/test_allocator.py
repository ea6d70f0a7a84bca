"""keep_freed_blocks: a freed 64 MB block (above glibc's adaptive mmap limit, 32 MiB) is reused by the next
allocation instead of mapped and faulted in again, as it is in a process with glibc's defaults."""

import subprocess
import sys

import pytest

from m2h_ros.allocator import keep_freed_blocks

# Minor page faults of 10 allocations of 64 MB that touch every page (after one that grows the heap).
MEASURE = """
import resource
import numpy as np
np.ones(64 << 20, np.uint8)
before = resource.getrusage(resource.RUSAGE_SELF).ru_minflt
for _ in range(10):
    block = np.ones(64 << 20, np.uint8)
    del block
faults = resource.getrusage(resource.RUSAGE_SELF).ru_minflt - before
"""


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="glibc's mallopt")
def test_freed_large_blocks_are_reused():
    fresh = subprocess.run([sys.executable, "-c", MEASURE + "print(faults)"], capture_output=True, text=True, check=True)
    assert int(fresh.stdout) >= 100  # glibc's defaults: every allocation is mapped and faulted in afresh
    assert keep_freed_blocks()
    measured: dict = {}
    exec(MEASURE, measured)  # noqa: S102
    assert measured["faults"] <= 16
