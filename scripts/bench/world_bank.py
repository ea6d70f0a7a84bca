"""RIR bank build time of a ~150 m^2 home at 1 m spacing with the default acoustics (``AcousticsConfig()``):
K source nodes spread over the home computed on --workers processes (``bank_build.compute_sources``, as
``RirBank.build`` runs them) and extrapolated to every node, beside the fixed numpy workload timed in
the same run (``m2h_ros.machine.reference_seconds``); then what a source's time goes to (one source
under cProfile: libroom's ray tracer, its image-source model, the HRTF early part, the late part).

    python scripts/bench/world_bank.py [--sources 8] [--workers 2] [--repeats 2] [--ray local|ADDRESS] [--all]

The home is the example apartment (``sample_worlds.apartment_grid``) with every length x --scale (1.25:
its raster read at 6.25 cm a pixel instead of 5 cm, ~154 m^2 of floor), as a nav2 map with a world file
that keeps its widened doors doors (door_width 1.2 m). --noise draws SLAM-like walls; above the walls'
simplification tolerance (world setting wall_tolerance, 5 cm) a ragged wall keeps every jag as a face,
and the image-source model's cost grows with the faces cubed: the wall faces are printed first.
--all builds the whole bank as well (the real figure, not an extrapolation). Target: <= 30 min on 2 cores.
"""

from __future__ import annotations

import argparse
import cProfile
import pstats
import resource
import tempfile
import time
from pathlib import Path

import numpy as np

from m2h_ros.core.world.acoustics import AcousticsConfig, scene_surfaces, simulate_source
from m2h_ros.core.world.bank_build import compute_sources
from m2h_ros.core.world.rir_bank import RirBank
from m2h_ros.core.world.sample_worlds import write_home_map
from m2h_ros.core.world.worlds import load_world_with_report
from m2h_ros.machine import availability_line, load_average, reference_seconds

TARGET_S = 30 * 60.0
# What a source's time goes to: (label, part of a profiled function's name), cumulative over its calls.
PARTS = (("ray tracing (libroom)", "ray_tracing"), ("image-source model (libroom)", "image_source_model"),
         ("early part (HRIRs per image)", "_early_part"), ("late part (shaped noise)", "_late_part"),
         ("walls crossed by direct paths", "_walls_crossed"), ("surfaces", "scene_surfaces"))


def source_parts(scene, node: int, config: AcousticsConfig) -> tuple[float, dict[str, float]]:
    """Seconds of one source under cProfile and of its parts."""
    profile = cProfile.Profile()
    start = time.perf_counter()
    profile.runcall(simulate_source, scene, node, config)
    total = time.perf_counter() - start
    stats = pstats.Stats(profile).stats  # (file, line, function) -> (calls, ..., cumulative, callers)
    parts = {label: sum(entry[3] for (_, _, function), entry in stats.items() if name in function)
             for label, name in PARTS}
    return total, parts


def _children_cpu() -> float:
    """User + system CPU seconds of this process's finished child processes (the pool's, once shut down)."""
    usage = resource.getrusage(resource.RUSAGE_CHILDREN)
    return usage.ru_utime + usage.ru_stime


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sources", type=int, default=8, help="K source nodes measured per repeat")
    parser.add_argument("--workers", type=int, default=2, help="processes (CPUs of --ray local)")
    parser.add_argument("--repeats", type=int, default=2, help="runs of the K sources")
    parser.add_argument("--ray", metavar="ADDRESS", default=None, help="as Ray tasks: 'local' or a cluster address")
    parser.add_argument("--scale", type=float, default=1.25, help="the apartment's lengths times this")
    parser.add_argument("--noise", type=float, default=0.0, help="SLAM-like walls, 0 (clean) to 1")
    parser.add_argument("--all", action="store_true", help="also build the whole bank and time it")
    args = parser.parse_args()
    config = AcousticsConfig()
    print(f"load average before: {load_average()}")
    print(availability_line())
    reference = min(reference_seconds() for _ in range(3))
    print(f"reference workload: {1e3 * reference:.1f} ms (best of 3)")
    with tempfile.TemporaryDirectory(prefix="m2h_bench_world_bank_") as root:
        root = Path(root)
        path = write_home_map(root / "home", scale=args.scale, noise=args.noise)
        scene, report = load_world_with_report(f"map:{path}")
        n_nodes = scene.grid.n_nodes
        area = sum(room.floor_area for room in scene.rooms)
        print(f"home: the apartment x {args.scale} (noise {args.noise}), {area:.0f} m^2 of floor, {report.describe()}; "
              f"{len(scene_surfaces(scene, config))} acoustic polygons; default acoustics: "
              f"{config.rir_length} s RIRs, image sources to order {config.ism_max_order}, {config.n_rays} rays")
        nodes = np.unique(np.linspace(0, n_nodes - 1, args.sources).round().astype(int)).tolist()
        way = f"Ray tasks ({args.ray})" if args.ray else f"{args.workers} local processes"
        per_source, cpu_per_source = [], []
        for repeat in range(args.repeats):
            bank = RirBank(scene, config, cache_dir=root / f"bank_{repeat}", progress=False)
            load = load_average()
            start, cpu = time.perf_counter(), _children_cpu()
            compute_sources(scene, config, nodes, bank.store, workers=args.workers, ray_address=args.ray,
                            progress=False)
            seconds, cpu = time.perf_counter() - start, _children_cpu() - cpu
            per_source.append(seconds / len(nodes))
            cpu_per_source.append(cpu / len(nodes))
            print(f"  run {repeat + 1}: {len(nodes)} sources {nodes} in {seconds:.1f} s on {way} "
                  f"({seconds / len(nodes):.2f} s per source; load average before {load})")
        median = float(np.median(per_source))
        print(f"per source on {way}: min {min(per_source):.2f} / median {median:.2f} / max {max(per_source):.2f} s "
              f"(wall time of K sources / K); {median / reference:.0f}x the reference workload")
        print(f"EXTRAPOLATION from {len(nodes)} measured sources, not a full build: {n_nodes} sources x "
              f"{median:.2f} s = {median * n_nodes / 60:.1f} min projected (spread "
              f"{min(per_source) * n_nodes / 60:.1f}-{max(per_source) * n_nodes / 60:.1f} min); target <= "
              f"{TARGET_S / 60:.0f} min on 2 cores: {'met' if median * n_nodes <= TARGET_S else 'MISSED'}")
        if not args.ray:  # Ray's workers are not this process's children: their CPU is not counted here
            cpu = float(np.median(cpu_per_source))
            print(f"CPU per source in the worker processes: min {min(cpu_per_source):.1f} / median {cpu:.1f} / max "
                  f"{max(cpu_per_source):.1f} s, so on {args.workers} free cores the bank would take "
                  f"{cpu * n_nodes / args.workers / 60:.1f} min (projected from CPU time, as the wall time is "
                  f"shared with whatever else runs)")
        node = nodes[len(nodes) // 2]
        total, parts = source_parts(scene, node, config)
        shares = ", ".join(f"{label} {seconds:.2f} s ({100 * seconds / total:.0f}%)" for label, seconds in parts.items())
        print(f"one source (node {node}) in this process under cProfile: {total:.2f} s: {shares}; "
              f"rest {total - sum(parts.values()):.2f} s ({100 * (1 - sum(parts.values()) / total):.0f}%)")
        if args.all:
            bank = RirBank(scene, config, cache_dir=root / "bank_all", progress=True)
            load = load_average()
            start = time.perf_counter()
            bank.build(workers=args.workers, ray_address=args.ray)
            seconds = time.perf_counter() - start
            print(f"whole bank: {n_nodes} sources in {seconds / 60:.1f} min on {way} (measured; load average "
                  f"before {load}), {bank.size_on_disk() / 2**30:.2f} GiB on disk; target "
                  f"{'met' if seconds <= TARGET_S else 'MISSED'}")
    print(f"load average after: {load_average()}")


if __name__ == "__main__":
    main()
