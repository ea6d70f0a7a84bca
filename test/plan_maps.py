"""Floor plans drawn from rectangles and written as nav2 maps: the inputs of the map world tests."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from m2h_ros.core.world.frames import FREE, OCCUPIED, UNKNOWN, OccupancyGrid
from m2h_ros.core.world.ros_map import write_ros_map


def map_spec(folder: Path, grid: OccupancyGrid, **options) -> str:
    """Write ``grid`` as a nav2 map into ``folder`` and return its world spec."""
    return f"map:{write_ros_map(folder / 'map.yaml', grid, **options)}"


def plan_grid(free, *, footprint, solid=(), res: float = 0.05, margin: float = 0.3) -> OccupancyGrid:
    """A plan raster from rectangles (xmin, ymin, xmax, ymax): a cell whose centre lies in a free rectangle
    is free, else in a solid one or the footprint occupied, else unknown; cell (0, 0)'s corner at the
    footprint's corner less ``margin``."""
    x0, y0 = footprint[0] - margin, footprint[1] - margin
    cols = int(round((footprint[2] + margin - x0) / res))
    rows = int(round((footprint[3] + margin - y0) / res))
    xs, ys = x0 + (np.arange(cols) + 0.5) * res, y0 + (np.arange(rows) + 0.5) * res

    def inside(rect) -> np.ndarray:
        return ((ys > rect[1]) & (ys < rect[3]))[:, None] & ((xs > rect[0]) & (xs < rect[2]))[None, :]

    cells = np.where(inside(footprint), OCCUPIED, UNKNOWN).astype(np.int8)
    for rect in free:
        cells[inside(rect)] = FREE
    for rect in solid:
        cells[inside(rect)] = OCCUPIED
    return OccupancyGrid(cells, res, (x0, y0))


def box_grid(width: float, depth: float, *, wall: float = 0.1) -> OccupancyGrid:
    """One room, floor [0, width] x [0, depth] metres, in walls ``wall`` thick."""
    return plan_grid([(0.0, 0.0, width, depth)], footprint=(-wall, -wall, width + wall, depth + wall))
