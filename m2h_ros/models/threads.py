"""How many torch threads a separator step should use, by batch size.

At batch 1 a step is about 24 small convolutions whose cost is per-call overhead, which a second
thread cannot split; it only adds a wake-up per operator, and loses outright whenever the other core
is busy. The threshold comes from the thread sweep of ``scripts/bench/separator.py`` (fused compact
model, 1 and 2 threads timed in alternation, 2-core shared machine, load average 6-13): one thread
was fastest at batch 1, 2 and 4 in every sweep and at batch 8 in two of three; two threads won at
batch 16 in two of three; at batch 32 one thread won all three (under that load the second core is
rarely free). Above the threshold this uses every core the process may run on, as torch would by
default; on an idle machine or one with more cores that is the likely winner, but it is not
measured here (docs/design/separator.md, Inference speed).

Usage (``torch.set_num_threads`` is process-wide, so set it once per run, not per step)::

    torch.set_num_threads(inference_threads(batch_size))

``torch_threads(n)`` sets it for one block and puts it back (a switch costs well under a microsecond).
"""

from __future__ import annotations

import os
from collections.abc import Iterator
from contextlib import contextmanager

import torch

from m2h_ros.errors import ConfigError

# Largest batch that runs fastest on one thread (measured on 2 cores; see the module docstring).
SINGLE_THREAD_MAX_BATCH = 8


def available_cpus() -> int:
    """CPUs this process may run on (its affinity mask, which containers and taskset narrow)."""
    if hasattr(os, "sched_getaffinity"):
        return len(os.sched_getaffinity(0))
    return os.cpu_count() or 1


def inference_threads(batch_size: int, *, cpus: int | None = None) -> int:
    """Torch intra-op threads for separator inference at ``batch_size`` clips per step."""
    if not isinstance(batch_size, int) or isinstance(batch_size, bool) or batch_size < 1:
        raise ConfigError(f"batch_size must be a positive int, got {batch_size!r}")
    cpus = available_cpus() if cpus is None else cpus
    if not isinstance(cpus, int) or isinstance(cpus, bool) or cpus < 1:
        raise ConfigError(f"cpus must be a positive int, got {cpus!r}")
    return 1 if batch_size <= SINGLE_THREAD_MAX_BATCH else cpus


@contextmanager
def torch_threads(n: int) -> Iterator[None]:
    """Run the block with ``n`` torch intra-op threads, then restore the process's count."""
    before = torch.get_num_threads()
    if n != before:
        torch.set_num_threads(n)
    try:
        yield
    finally:
        if n != before:
            torch.set_num_threads(before)
