"""Scripted floor plans as occupancy grids, standing in for a robot's own map: an apartment (the example
map of the docs) and two rooms joined by a corridor of a chosen width (for tests of narrow gaps).

A plan is rectangles in its own frame (metres): free rectangles (rooms, door openings), solid ones
(furniture) and a footprint (the outer walls' outline). Rasterised: a cell is free when it lies wholly
inside a free rectangle, so an opening is never wider on the grid than on the plan; it is occupied
when it lies inside the footprint and is not free, or touches furniture; everything else is unknown.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
from scipy import ndimage

from m2h_ros.core.world.frames import FREE, OCCUPIED, UNKNOWN, OccupancyGrid
from m2h_ros.core.world.ros_map import write_ros_map
from m2h_ros.errors import ConfigError

Rect = tuple[float, float, float, float]  # xmin, ymin, xmax, ymax (metres)

APARTMENT_SIZE = (12.0, 9.0)  # outer wall to outer wall; outer walls 0.15 m, inner walls 0.10 m thick
APARTMENT_MARGIN = 1.0  # unknown beyond the outer walls
# The rooms' floors, wall face to wall face (about 98 m^2 in all).
APARTMENT_ROOMS: dict[str, Rect] = {
    "living_room": (0.15, 0.15, 6.45, 3.95),
    "kitchen": (6.55, 0.15, 11.85, 3.95),
    "hallway": (0.15, 4.05, 11.85, 5.25),
    "bedroom_1": (0.15, 5.35, 4.25, 8.85),
    "bedroom_2": (4.35, 5.35, 9.25, 8.85),
    "bath": (9.35, 5.35, 11.85, 8.85),
}
DOOR_REACH = 0.3  # a door's free rectangle runs this far into both rooms, so it joins them on any grid
# Door openings: (rooms joined, opening along the wall as (from, to), axis of the wall, wall's span across).
_DOORS = (
    ("living_room", "hallway", (2.50, 3.35), "x", (3.95, 4.05)),
    ("kitchen", "hallway", (8.60, 9.45), "x", (3.95, 4.05)),
    ("living_room", "kitchen", (1.40, 2.25), "y", (6.45, 6.55)),
    ("bedroom_1", "hallway", (3.00, 3.85), "x", (5.25, 5.35)),
    ("bedroom_2", "hallway", (5.20, 6.05), "x", (5.25, 5.35)),
    ("bath", "hallway", (10.20, 11.00), "x", (5.25, 5.35)),
)
APARTMENT_DOORS: dict[tuple[str, str], Rect] = {
    (a, b): ((lo, across[0] - DOOR_REACH, hi, across[1] + DOOR_REACH) if axis == "x"
             else (across[0] - DOOR_REACH, lo, across[1] + DOOR_REACH, hi))
    for a, b, (lo, hi), axis, across in _DOORS}
# Isolated furniture, standing clear of every wall.
APARTMENT_FURNITURE: dict[str, Rect] = {
    "table": (2.70, 1.60, 3.30, 2.20),  # 0.6 x 0.6 m, living room
    "pillar": (9.40, 1.80, 9.80, 2.20),  # 0.4 x 0.4 m, kitchen
    "nightstand": (0.75, 8.00, 1.25, 8.40),  # bedroom 1
    "cabinet": (7.20, 6.75, 8.00, 7.25),  # bedroom 2
}
_EPS = 1e-9  # plan coordinates that land on a cell edge count as on it, whatever the rounding


def apartment_grid(*, resolution: float = 0.05, yaw: float = 0.0, seed: int = 0,
                   noise: float = 0.0) -> OccupancyGrid:
    """The apartment: 12 x 9 m, six rooms (living room, kitchen, hallway, two bedrooms, bath) joined by
    0.8-0.85 m doors, four furniture blocks, unknown outside its walls and in a 1 m margin.

    The grid frame is the plan turned by ``yaw`` (radians) about the apartment's centre, so the centre is
    at (6, 4.5) in the map frame whatever the yaw (``apartment_to_map`` places plan points). ``noise``
    (0..1) makes it look like a SLAM map: wall faces ragged by a cell or two, unknown cells along walls and
    a few unknown specks in the rooms, drawn from ``seed``; 0 is the clean plan."""
    if not (math.isfinite(noise) and 0.0 <= noise <= 1.0):
        raise ConfigError(f"apartment noise must be in [0, 1], not {noise}")
    width, height = APARTMENT_SIZE
    cells = _raster(free=[*APARTMENT_ROOMS.values(), *APARTMENT_DOORS.values()],
                    solid=list(APARTMENT_FURNITURE.values()), footprint=(0.0, 0.0, width, height),
                    margin=APARTMENT_MARGIN, resolution=resolution)
    if noise > 0:
        cells = _slam_look(cells, np.random.default_rng(seed), noise)
    corner = apartment_to_map([-APARTMENT_MARGIN, -APARTMENT_MARGIN], yaw=yaw)
    return OccupancyGrid(cells, resolution, (float(corner[0]), float(corner[1])), float(yaw))


def write_home_map(folder, *, scale: float = 1.0, noise: float = 0.0):
    """The apartment as a nav2 map (``folder/map.yaml``) with every length times ``scale`` (its 5 cm raster
    read at ``0.05 * scale`` m a pixel: 1.25 gives a ~154 m^2 home), beside a world file that keeps its
    widened doors doors (door_width 1.2 m at any scale up to 1.4). Returns the map.yaml path."""
    if not (math.isfinite(scale) and 0.5 <= scale <= 1.4):
        raise ConfigError(f"home scale must be in [0.5, 1.4] (its 0.85 m doors stay under 1.2 m), not {scale}")
    plan = apartment_grid(resolution=0.05, noise=noise)
    path = write_ros_map(Path(folder) / "map.yaml", OccupancyGrid(plan.cells, 0.05 * scale, plan.origin))
    (Path(folder) / "map.world.yaml").write_text("door_width: 1.2  # the apartment's 0.8-0.85 m doors, scaled\n")
    return path


def apartment_to_map(points, *, yaw: float = 0.0) -> np.ndarray:
    """Map-frame coordinates (..., 2) of apartment plan points (..., 2) on a grid of ``apartment_grid(yaw=...)``."""
    centre = np.array(APARTMENT_SIZE) / 2
    c, s = math.cos(yaw), math.sin(yaw)
    offset = np.asarray(points, np.float64) - centre
    return centre + np.stack([c * offset[..., 0] - s * offset[..., 1], s * offset[..., 0] + c * offset[..., 1]],
                             axis=-1)


def corridor_grid(width_m: float, *, length_m: float = 1.0, room_m: float = 3.0, wall_m: float = 0.10,
                  resolution: float = 0.05) -> OccupancyGrid:
    """Two ``room_m`` square rooms side by side (left one from x = 0), joined only by a corridor
    ``width_m`` wide and ``length_m`` long through the solid between them, centred at y = room_m / 2;
    walls ``wall_m`` thick, 0.5 m of unknown around. On the grid the corridor spans the cells wholly
    inside it: a whole number of cells, never wider than ``width_m``."""
    for name, value in (("width_m", width_m), ("length_m", length_m), ("room_m", room_m), ("wall_m", wall_m)):
        if not (math.isfinite(value) and value > 0):
            raise ConfigError(f"corridor_grid {name} must be > 0, not {value}")
    if width_m >= room_m:
        raise ConfigError(f"corridor_grid width_m ({width_m}) must be below room_m ({room_m})")
    right = room_m + length_m
    mid = room_m / 2
    corridor = (room_m - DOOR_REACH, mid - width_m / 2, right + DOOR_REACH, mid + width_m / 2)
    cells = _raster(free=[(0.0, 0.0, room_m, room_m), corridor, (right, 0.0, right + room_m, room_m)],
                    solid=[], footprint=(-wall_m, -wall_m, right + room_m + wall_m, room_m + wall_m),
                    margin=0.5, resolution=resolution)
    return OccupancyGrid(cells, resolution, (-wall_m - 0.5, -wall_m - 0.5))


def _raster(*, free: list[Rect], solid: list[Rect], footprint: Rect, margin: float,
            resolution: float) -> np.ndarray:
    """(rows, cols) int8 cells of a plan; cell (0, 0)'s outer corner at the footprint's corner less ``margin``."""
    if not (math.isfinite(resolution) and 0 < resolution <= 0.2):
        raise ConfigError(f"plan resolution must be in (0, 0.2] m (coarser closes doors), not {resolution}")
    x0, y0 = footprint[0] - margin, footprint[1] - margin
    cols = math.ceil((footprint[2] + margin - x0) / resolution - _EPS)
    rows = math.ceil((footprint[3] + margin - y0) / resolution - _EPS)
    edges_x, edges_y = x0 + np.arange(cols) * resolution, y0 + np.arange(rows) * resolution

    def within(rect: Rect) -> np.ndarray:  # cells wholly inside
        xs = (edges_x >= rect[0] - _EPS) & (edges_x + resolution <= rect[2] + _EPS)
        ys = (edges_y >= rect[1] - _EPS) & (edges_y + resolution <= rect[3] + _EPS)
        return ys[:, None] & xs[None, :]

    def touching(rect: Rect) -> np.ndarray:  # cells that overlap it
        xs = (edges_x < rect[2] - _EPS) & (edges_x + resolution > rect[0] + _EPS)
        ys = (edges_y < rect[3] - _EPS) & (edges_y + resolution > rect[1] + _EPS)
        return ys[:, None] & xs[None, :]

    cells = np.where(touching(footprint), OCCUPIED, UNKNOWN).astype(np.int8)
    for rect in free:
        cells[within(rect)] = FREE
    for rect in solid:
        cells[touching(rect)] = OCCUPIED
    return cells


def _slam_look(cells: np.ndarray, rng: np.random.Generator, noise: float) -> np.ndarray:
    """Ragged walls (free cells beside them turned occupied, one or two deep), unknown cells along walls,
    and unknown specks in free space. Walls only grow, so no opening appears in one."""
    cells = cells.copy()
    cross = ndimage.generate_binary_structure(2, 1)
    for chance in (0.5 * noise, 0.25 * noise):  # the second pass deepens some bumps to two cells
        face = (cells == FREE) & ndimage.binary_dilation(cells == OCCUPIED, cross)
        cells[face & (rng.random(cells.shape) < chance)] = OCCUPIED
    face = (cells == FREE) & ndimage.binary_dilation(cells == OCCUPIED, cross)
    cells[face & (rng.random(cells.shape) < 0.08 * noise)] = UNKNOWN
    free_rows, free_cols = np.nonzero(cells == FREE)
    picks = rng.choice(free_rows.size, size=round(40 * noise), replace=False)
    for row, col in zip(free_rows[picks], free_cols[picks]):
        extent = rng.integers(1, 3)  # specks of 1 x 1 or 2 x 2 cells
        speck = cells[row:row + extent, col:col + extent]
        speck[speck == FREE] = UNKNOWN
    return cells
