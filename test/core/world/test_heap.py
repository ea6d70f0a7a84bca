"""retain_freed_memory: glibc keeps freed blocks, so allocating them again touches no new pages."""

import subprocess
import sys

import pytest

from m2h_ros.core.world.heap import retain_freed_memory

# Six 8 MiB blocks freed together (what an env reset does at a larger scale), then allocated and
# written again; prints the page faults of the second round. In a fresh process: the setting is
# process-wide and this test process may have set it already.
SCRIPT = """
import resource, sys
import numpy as np
from m2h_ros.core.world.heap import retain_freed_memory
if sys.argv[1] == "retain":
    assert retain_freed_memory()
for round in range(2):
    if round:
        before = resource.getrusage(resource.RUSAGE_SELF).ru_minflt
    blocks = [np.ones(2**21, np.float32) for _ in range(6)]
    del blocks
print(resource.getrusage(resource.RUSAGE_SELF).ru_minflt - before)
"""


def faults(mode: str) -> int:
    return int(subprocess.run([sys.executable, "-c", SCRIPT, mode], check=True, capture_output=True,
                              text=True).stdout)


def test_freed_memory_is_reused_without_page_faults():
    if not retain_freed_memory():
        pytest.skip("malloc is not glibc's")
    pages = 6 * 8 * 2**20 // 4096
    assert faults("default") > pages / 10   # glibc gave (part of) the 48 MiB back, to fault in again
    assert faults("retain") < pages / 100
