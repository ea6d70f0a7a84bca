"""What this machine is (:func:`machine_description`, recorded beside a training run's wall times) and what
its cores are free for right now, for benchmarks to print beside their figures.

On a shared machine a throughput figure says as much as the cores were free. The load average does
not tell it all: with the kernel's autogroup scheduling (``/proc/sys/kernel/sched_autogroup_enabled``)
CPU time is shared between sessions first, so a job started at nice 19 from another session still
takes its session's fair share of the cores. Measure instead.
"""

from __future__ import annotations

import multiprocessing
import os
import platform
import resource
import time
from pathlib import Path
from typing import Any

import numpy as np

AUTOGROUP = Path("/proc/sys/kernel/sched_autogroup_enabled")


def machine_description() -> dict[str, Any]:
    """CPU model and count, platform, Python and torch versions (wall times mean little without them)."""
    import torch  # here, not at the top: the benches that only measure cores need no torch

    model = platform.processor() or platform.machine()
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                model = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    return {"cpu_model": model, "cpu_count": os.cpu_count(), "platform": platform.platform(),
            "python": platform.python_version(), "torch": str(torch.__version__)}


def reference_seconds() -> float:
    """Wall-clock seconds of a fixed numpy workload (~0.1 s on one free core): a benchmark divides its
    figure by this, measured in the same run, so machines and loads compare."""
    start, values = time.perf_counter(), np.ones(1 << 20, np.float32)
    for _ in range(300):
        np.sqrt(values, out=values)
    return time.perf_counter() - start


def _spin(queue) -> None:
    queue.put(reference_seconds())


def cores_available() -> float:
    """How many cores two processes of the same numpy work get at once: 2 x (time of one alone) /
    (time of two together); 2.0 on two free cores, ~1 when another job holds one of them."""
    context = multiprocessing.get_context("fork")
    times = []
    for count in (1, 2):
        queue = context.Queue()
        workers = [context.Process(target=_spin, args=(queue,)) for _ in range(count)]
        for worker in workers:
            worker.start()
        times.append(max(queue.get() for _ in workers))
        for worker in workers:
            worker.join()
    return 2 * times[0] / times[1]


def autogroup_scheduling() -> bool:
    return AUTOGROUP.exists() and AUTOGROUP.read_text().strip() == "1"


def load_averages() -> list[float]:
    """The 1, 5 and 15 minute load averages, rounded to 0.01, as results files record them."""
    return [round(x, 2) for x in os.getloadavg()]


def load_average() -> str:
    """The 1, 5 and 15 minute load averages, as a benchmark prints them ("0.52, 0.61, 0.70")."""
    return ", ".join(f"{x:.2f}" for x in os.getloadavg())


def availability_line() -> str:
    """One line for a benchmark's output: cores available to two processes, load average, scheduler."""
    return (f"cores available to two processes: {cores_available():.2f} of {os.cpu_count()} (load average "
            f"{os.getloadavg()[0]:.1f}; autogroup scheduling {'on' if autogroup_scheduling() else 'off'}"
            f"{': start benches with setsid, other sessions share the cores first' if autogroup_scheduling() else ''})")


def process_cpu_seconds(pid: int) -> float:
    """User + system CPU seconds of a running process so far (Linux ``/proc``): a benchmark adds its
    helper processes' CPU to its own this way."""
    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def peak_rss_mib() -> float:
    """This process's own peak resident memory in MiB: ``VmHWM`` from ``/proc/self/status``.

    Not ``getrusage``'s ``ru_maxrss``: Linux keeps that across ``fork`` + ``exec``, so a process spawned
    by a parent holding 3 GB reports 3 GB before it allocates anything. ``VmHWM`` belongs to the address
    space, which ``exec`` replaces. Falls back to ``ru_maxrss`` where there is no ``/proc``."""
    try:
        for line in Path("/proc/self/status").read_text().splitlines():
            if line.startswith("VmHWM:"):
                return int(line.split()[1]) / 1024
    except OSError:
        pass
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
