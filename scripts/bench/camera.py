"""Camera render cost: cold render per view, and warm batches of 16 views from the view cache, beside a
fixed numpy workload timed in the same run (m2h_ros.machine.reference_seconds) and the load.

    python scripts/bench/camera.py [--size 128] [--scenes 3]
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from m2h_ros.core.world.camera import CameraConfig, CameraViews
from m2h_ros.core.world.scene import load_split
from m2h_ros.machine import availability_line, load_average, reference_seconds


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--size", type=int, default=128, help="width = height, pixels")
    parser.add_argument("--scenes", type=int, default=3, help="train scenes to measure")
    parser.add_argument("--batches", type=int, default=500, help="warm batches per scene")
    args = parser.parse_args()
    config = CameraConfig(width=args.size, height=args.size)
    print(f"load average before: {load_average()}")
    print(availability_line())
    reference_ms = 1e3 * min(reference_seconds() for _ in range(3))
    rng = np.random.default_rng(0)
    cold, warm = [], []
    n_views = 0
    for scene in load_split("train")[:args.scenes]:
        views = CameraViews(scene, config)
        start = time.perf_counter()
        views.prerender()
        cold.append(time.perf_counter() - start)
        n_views += scene.grid.n_nodes * 4
        nodes = rng.integers(scene.grid.n_nodes, size=(args.batches, 16))
        headings = rng.integers(4, size=(args.batches, 16))
        start = time.perf_counter()
        for batch_nodes, batch_headings in zip(nodes, headings):
            views.views(batch_nodes, batch_headings)
        warm.append((time.perf_counter() - start) / args.batches)
    cold_ms = 1e3 * sum(cold) / n_views
    warm_ms = 1e3 * float(np.mean(warm))
    print(f"camera {args.size}x{args.size}, {args.scenes} train scenes, {n_views} poses")
    print(f"cold render:          {cold_ms:8.3f} ms/view  ({1e3 * np.mean(cold):.0f} ms per scene, all poses)")
    print(f"warm batch of 16:     {warm_ms:8.3f} ms/batch = {warm_ms / 16:.4f} ms/view")
    print(f"cold / warm per view: {cold_ms / (warm_ms / 16):8.1f}x")
    print(f"reference workload:   {reference_ms:8.1f} ms (best of 3); cold view = {cold_ms / reference_ms:.4f} x, "
          f"warm batch = {warm_ms / reference_ms:.4f} x the reference")
    print(f"load average after: {load_average()}")


if __name__ == "__main__":
    main()
