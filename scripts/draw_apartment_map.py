#!/usr/bin/env python3
"""Write the example apartment as a nav2 map (map.yaml + map.pgm, as map_saver_cli writes them).

    python scripts/draw_apartment_map.py --out DIR [--resolution 0.05] [--yaw DEG] [--noise 0.3] [--seed 0]

A 12 x 9 m apartment of six rooms (m2h_ros.core.world.sample_worlds.apartment_grid); --noise 0 draws the
clean plan, larger values (up to 1) a more SLAM-like map; --yaw turns the map about the apartment's centre.
"""

from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path

from m2h_ros.core.world.ros_map import write_ros_map
from m2h_ros.core.world.sample_worlds import apartment_grid
from m2h_ros.errors import reports_errors


@reports_errors("draw_apartment_map")
def main(argv: list[str] | None = None) -> int | None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, required=True, help="folder for map.yaml and map.pgm")
    parser.add_argument("--resolution", type=float, default=0.05, help="metres per pixel")
    parser.add_argument("--yaw", type=float, default=0.0, help="degrees, the map's turn in the map frame")
    parser.add_argument("--noise", type=float, default=0.3, help="0 (clean plan) to 1 (ragged SLAM map)")
    parser.add_argument("--seed", type=int, default=0, help="draws the noise")
    args = parser.parse_args(argv)

    grid = apartment_grid(resolution=args.resolution, yaw=math.radians(args.yaw), seed=args.seed,
                          noise=args.noise)
    path = write_ros_map(args.out / "map.yaml", grid)
    print(f"wrote {path} and {path.with_suffix('.pgm')} ({grid.cells.shape[1]} x {grid.cells.shape[0]} px)")


if __name__ == "__main__":
    sys.exit(main())
