#!/usr/bin/env python3
"""What each node costs to start: a fresh Python process importing the node's module, CPU and wall time,
against a process importing only rclpy's Node (what no ROS 2 Python node avoids) in the same run,
interleaved. A run starts five to seven nodes on the same cores, so this is paid five to seven times.

    python scripts/bench/node_start.py [--repeats 8]
"""

from __future__ import annotations

import argparse
import resource
import statistics
import subprocess
import sys
import time

from m2h_ros.machine import availability_line, load_average
from m2h_ros.node_configs import NODE_CONFIGS

REFERENCE = "rclpy.node"


def start_cost(module: str) -> tuple[float, float]:
    """(CPU seconds, wall seconds) of a fresh interpreter importing ``module``."""
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    started = time.perf_counter()
    subprocess.run([sys.executable, "-c", f"import {module}"], check=True)
    wall = time.perf_counter() - started
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    return after.ru_utime + after.ru_stime - before.ru_utime - before.ru_stime, wall


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=8, help="starts of each module")
    args = parser.parse_args(argv)
    print(availability_line(), flush=True)
    modules = (REFERENCE, *(f"m2h_ros.nodes.{node}" for node in NODE_CONFIGS))
    for module in modules:  # warm: the page cache holds every library afterwards
        start_cost(module)
    costs: dict[str, list[tuple[float, float]]] = {module: [] for module in modules}
    for _ in range(args.repeats):
        for module in modules:  # interleaved: each sees the same load
            costs[module].append(start_cost(module))
    reference_cpu = statistics.median(cpu for cpu, _ in costs[REFERENCE])
    print(f"{args.repeats} starts each, median (min-max)")
    for module, runs in costs.items():
        cpu, wall = [c for c, _ in runs], [w for _, w in runs]
        print(f"{module:34s} CPU {statistics.median(cpu):.2f} s ({min(cpu):.2f}-{max(cpu):.2f}), wall "
              f"{statistics.median(wall):.2f} s, {statistics.median(cpu) / reference_cpu:.2f}x {REFERENCE}'s CPU")
    print(f"load average after: {load_average()}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
