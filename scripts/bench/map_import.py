"""Map import cost: seconds from a nav2 map.yaml to a world (``worlds.load_world``: read, rooms, walls,
furniture, lattice, camera mesh), for a 25 m x 25 m map at 5 cm and for the example apartment, beside
two references timed in the same run: the map read alone (``ros_map.read_ros_map``) and the fixed numpy
workload (``m2h_ros.machine.reference_seconds``); then where the time goes (one profiled import).

    python scripts/bench/map_import.py [--repeats 3] [--noise 0.3]

The 25 m map is four copies of the apartment (``sample_worlds.apartment_grid``, SLAM-like walls of
--noise, each copy its own draw) two by two, joined by doors cut through the walls between them, in a
500 x 500 raster with unknown space round them: 24 x 18 m of building. Each repeat imports a fresh
copy of the files (worlds are memoised per file), so every figure is a whole import. Target: <= 30 s.
"""

from __future__ import annotations

import argparse
import cProfile
import pstats
import shutil
import tempfile
import time
from pathlib import Path

import numpy as np

from m2h_ros.core.world.frames import FREE, UNKNOWN, OccupancyGrid
from m2h_ros.core.world.ros_map import read_ros_map, write_ros_map
from m2h_ros.core.world.sample_worlds import APARTMENT_MARGIN, APARTMENT_SIZE, apartment_grid
from m2h_ros.core.world.worlds import load_world_with_report
from m2h_ros.machine import availability_line, load_average, reference_seconds

RESOLUTION = 0.05
RASTER = 500  # pixels a side: 25 m at 5 cm
TARGET_S = 30.0
# Doors cut between the copies (plan metres of the two-by-two building, from its lower-left corner):
# hallway to hallway across the vertical seam, bedroom to living room across the horizontal one.
_SEAM_DOORS = ((11.55, 4.30, 12.45, 5.00), (11.55, 13.30, 12.45, 14.00),
               (2.00, 8.55, 2.85, 9.45), (14.00, 8.55, 14.85, 9.45))
# Where the time goes: the builder's stages, by function (cumulative time over all their calls).
STAGES = (("read (ros_map.read_ros_map)", "read_ros_map"), ("rooms (watershed, merges)", "_rooms"),
          ("boundaries (trace, split, simplify)", "_room_rings"), ("surfaces (walls, floors)", "_room_surfaces"),
          ("furniture", "_furniture"), ("lattice (phases, edges, detours)", "_lattice"),
          ("camera mesh (triangulation)", "_surfaces_mesh"))


def four_apartments(noise: float) -> OccupancyGrid:
    """The two-by-two building in a RASTER x RASTER map."""
    width, height = APARTMENT_SIZE
    margin = round(APARTMENT_MARGIN / RESOLUTION)
    rows, cols = round(height / RESOLUTION), round(width / RESOLUTION)
    cells = np.full((RASTER, RASTER), UNKNOWN, np.int8)
    row0, col0 = (RASTER - 2 * rows) // 2, (RASTER - 2 * cols) // 2
    for index in range(4):
        copy = apartment_grid(resolution=RESOLUTION, seed=index, noise=noise).cells
        r, c = row0 + (index // 2) * rows, col0 + (index % 2) * cols
        cells[r:r + rows, c:c + cols] = copy[margin:margin + rows, margin:margin + cols]
    for x0, y0, x1, y1 in _SEAM_DOORS:
        cells[row0 + round(y0 / RESOLUTION):row0 + round(y1 / RESOLUTION),
              col0 + round(x0 / RESOLUTION):col0 + round(x1 / RESOLUTION)] = FREE
    return OccupancyGrid(cells, RESOLUTION, (0.0, 0.0))


def timed_imports(source: Path, work: Path, repeats: int) -> tuple[list[float], list[float], str]:
    """Seconds of ``repeats`` whole imports and of as many bare reads, each of a fresh copy; the report."""
    imports, reads, report = [], [], ""
    for repeat in range(repeats):
        copy = work / f"{source.parent.name}_{repeat}"
        shutil.copytree(source.parent, copy)
        start = time.perf_counter()
        read_ros_map(copy / source.name)
        reads.append(time.perf_counter() - start)
        start = time.perf_counter()
        _, described = load_world_with_report(f"map:{copy / source.name}")
        imports.append(time.perf_counter() - start)
        report = described.describe()
    return imports, reads, report


def stage_seconds(source: Path, work: Path) -> tuple[float, dict[str, float]]:
    """One profiled import of a fresh copy: its total and the builder's stages' cumulative seconds."""
    copy = work / f"{source.parent.name}_profiled"
    shutil.copytree(source.parent, copy)
    profile = cProfile.Profile()
    start = time.perf_counter()
    profile.runcall(load_world_with_report, f"map:{copy / source.name}")
    total = time.perf_counter() - start
    stats = pstats.Stats(profile).stats  # (file, line, function) -> (calls, ..., cumulative, callers)
    by_name = {}
    for (file, _, function), (_, _, _, cumulative, _) in stats.items():
        if file.endswith(("plan_world.py", "ros_map.py")):
            by_name[function] = by_name.get(function, 0.0) + cumulative
    return total, {label: by_name.get(function, 0.0) for label, function in STAGES}


def spread(values: list[float]) -> str:
    return f"min {min(values):.3f} / median {float(np.median(values)):.3f} / max {max(values):.3f} s"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=3, help="imports per map")
    parser.add_argument("--noise", type=float, default=0.3, help="the copies' SLAM look (0: clean plans)")
    args = parser.parse_args()
    print(f"load average before: {load_average()}")
    print(availability_line())
    reference = min(reference_seconds() for _ in range(3))
    print(f"reference workload: {1e3 * reference:.1f} ms (best of 3)")
    with tempfile.TemporaryDirectory(prefix="m2h_bench_map_") as root:
        root = Path(root)
        large = write_ros_map(root / "four_apartments" / "map.yaml", four_apartments(args.noise))
        apartment = write_ros_map(root / "apartment" / "map.yaml",
                                  apartment_grid(resolution=RESOLUTION, noise=args.noise))
        for name, path in (("25 m x 25 m map (500 x 500 px, four apartments)", large),
                           ("example apartment (280 x 220 px)", apartment)):
            imports, reads, report = timed_imports(path, root, args.repeats)
            median = float(np.median(imports))
            print(f"{name}: {report}")
            print(f"  import: {spread(imports)} ({args.repeats} runs, target <= {TARGET_S:.0f} s: "
                  f"{'met' if max(imports) <= TARGET_S else 'MISSED'}); load average {load_average()}")
            print(f"  map read alone: {spread(reads)}; import / read {median / float(np.median(reads)):.0f}x; "
                  f"import / reference workload {median / reference:.1f}x")
            total, stages = stage_seconds(path, root)
            shares = ", ".join(f"{label} {seconds:.2f} s ({100 * seconds / total:.0f}%)"
                               for label, seconds in stages.items())
            print(f"  where the time goes (one profiled import, {total:.2f} s with the profiler): {shares}; "
                  f"rest {total - sum(stages.values()):.2f} s")
    print(f"load average after: {load_average()}")


if __name__ == "__main__":
    main()
