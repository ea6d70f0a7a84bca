"""How many torch threads a separator step should use, by batch size.

At batch 1 a step is about 24 small convolutions whose cost is per-call overhead, which a second
thread cannot split; it only adds a wake-up per operator, and loses outright whenever the other core
is busy (on the shared 2-core machines, 2 threads made a batch-1 step 2-3x slower than 1). From a
few clips per batch on, each convolution has enough arithmetic for more cores to pay. The threshold
comes from ``scripts/bench/separator.py`` (its thread sweep over batch sizes, fused compact model,
2 cores); more than 2 cores were not measured, so above the threshold this uses every core the
process may run on, as torch would by default.

Usage (``torch.set_num_threads`` is process-wide, so set it once per run, not per step)::

    torch.set_num_threads(inference_threads(batch_size))
"""

from __future__ import annotations

import os

from m2h_ros.errors import ConfigError

# Largest batch that runs fastest on one thread (measured on 2 cores; see the module docstring).
SINGLE_THREAD_MAX_BATCH = 2


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
