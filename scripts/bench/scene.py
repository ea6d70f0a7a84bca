"""Scene generation cost: ms per procedural scene (floor plan, furnishings, navigation grid), by preset,
beside a fixed numpy workload timed in the same run (m2h_ros.machine.reference_seconds) and the load.

    python scripts/bench/scene.py [--seeds 20] [--repeats 3]

Each repeat clears the scene cache and generates --seeds scenes; the best repeat is reported.
"""

from __future__ import annotations

import argparse
import time

from m2h_ros.core.world import scene as scene_module
from m2h_ros.machine import availability_line, load_average, reference_seconds


def ms_per_scene(preset: str, seeds: int, repeats: int) -> float:
    best = float("inf")
    for _ in range(repeats):
        scene_module._generate.cache_clear()  # each scene built, not looked up
        start = time.perf_counter()
        for seed in range(seeds):
            scene_module.generate_scene(seed, preset=preset)
        best = min(best, (time.perf_counter() - start) / seeds)
    return 1e3 * best


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, default=20, help="scenes per preset and repeat")
    parser.add_argument("--repeats", type=int, default=3, help="repeats per preset (best reported)")
    args = parser.parse_args()
    print(f"load average before: {load_average()}")
    print(availability_line())
    reference_ms = 1e3 * min(reference_seconds() for _ in range(args.repeats))
    print(f"reference workload: {reference_ms:8.1f} ms")
    for preset in ("small", "default"):
        ms = ms_per_scene(preset, args.seeds, args.repeats)
        print(f"{preset:>8} preset: {ms:8.2f} ms/scene = {ms / reference_ms:.3f} x the reference "
              f"({args.seeds} seeds, best of {args.repeats})")
    print(f"load average after: {load_average()}")


if __name__ == "__main__":
    main()
