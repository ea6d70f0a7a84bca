"""The robot's coordinate frames (REP 103 / REP 105), its velocity between observations and the floor
plan as an occupancy grid, in numbers: what TF, Odometry and OccupancyGrid messages carry.

Frames: ``map -> odom -> base_link -> head -> camera``. The simulator's odometry is exact, so ``map ->
odom`` is the identity; ``odom -> base_link`` is the robot's pose on the floor; ``head`` is where the
ears are (above base_link); ``camera`` is the camera's optical frame (z forward, x right, y down, as
sensor_msgs/Image expects), at the eyes.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from m2h_ros.core.world.scene import Scene

MAP, ODOM, BASE, HEAD, CAMERA = "map", "odom", "base_link", "head", "camera"
IDENTITY = (0.0, 0.0, 0.0, 1.0)
# Body (x forward, y left, z up) to optical (z forward, x right, y down): quaternion x, y, z, w.
OPTICAL = (-0.5, 0.5, -0.5, 0.5)
FREE, OCCUPIED, UNKNOWN = 0, 100, -1  # nav_msgs/OccupancyGrid cell values


@dataclass(frozen=True)
class Transform:
    parent: str
    child: str
    translation: tuple[float, float, float]
    rotation: tuple[float, float, float, float]  # quaternion x, y, z, w


def yaw_rotation(yaw: float) -> tuple[float, float, float, float]:
    return 0.0, 0.0, math.sin(yaw / 2), math.cos(yaw / 2)


def quaternion_yaw(x: float, y: float, z: float, w: float) -> float:
    """The rotation about +z of a quaternion (radians, -pi..pi)."""
    return math.atan2(2 * (w * z + x * y), 1 - 2 * (y * y + z * z))


def static_transforms(*, head_height: float, eye_height: float) -> tuple[Transform, ...]:
    """What does not move: map -> odom, base_link -> head, head -> camera (/tf_static)."""
    return (Transform(MAP, ODOM, (0.0, 0.0, 0.0), IDENTITY),
            Transform(BASE, HEAD, (0.0, 0.0, float(head_height)), IDENTITY),
            Transform(HEAD, CAMERA, (0.0, 0.0, float(eye_height - head_height)), OPTICAL))


def base_transform(pose) -> Transform:
    """odom -> base_link for a pose (x, y, yaw) on the floor (/tf)."""
    x, y, yaw = (float(v) for v in pose)
    return Transform(ODOM, BASE, (x, y, 0.0), yaw_rotation(yaw))


def twist(previous, pose, seconds: float) -> tuple[float, float, float]:
    """Mean velocity from ``previous`` to ``pose`` (each x, y, yaw) over ``seconds``, in base_link of the
    earlier pose (as nav_msgs/Odometry's twist): forward, leftward (m/s), turn rate (rad/s, the short
    way round). Zero when no time passed."""
    if not seconds > 0:
        return 0.0, 0.0, 0.0
    (x0, y0, yaw0), (x1, y1, yaw1) = (tuple(float(v) for v in p) for p in (previous, pose))
    dx, dy = x1 - x0, y1 - y0
    c, s = math.cos(yaw0), math.sin(yaw0)
    turn = math.remainder(yaw1 - yaw0, 2 * math.pi)
    return (c * dx + s * dy) / seconds, (-s * dx + c * dy) / seconds, turn / seconds


@dataclass(frozen=True)
class OccupancyGrid:
    """A floor plan raster as nav_msgs/OccupancyGrid and nav2's map_server hold one: row 0 is the
    bottom row (smallest y of the grid's own frame), cell (ix, iy) is ``cells[iy, ix]``, and the grid
    frame is the map frame turned by ``yaw`` about ``origin``."""
    cells: np.ndarray  # (rows along y, columns along x) int8: FREE, OCCUPIED or UNKNOWN
    resolution: float  # metres per cell
    origin: tuple[float, float]  # map coordinates of cell (0, 0)'s outer corner
    yaw: float = 0.0  # radians, the grid's rotation in the map frame (map.yaml's third origin value)

    def cell_centres(self, ix, iy) -> np.ndarray:
        """(..., 2) map coordinates of the centres of cells (ix, iy) (arrays broadcast)."""
        u = (np.asarray(ix, np.float64) + 0.5) * self.resolution
        v = (np.asarray(iy, np.float64) + 0.5) * self.resolution
        c, s = math.cos(self.yaw), math.sin(self.yaw)
        return np.stack([self.origin[0] + c * u - s * v, self.origin[1] + s * u + c * v], axis=-1)

    def cell_of(self, xy) -> tuple[np.ndarray, np.ndarray]:
        """Integer cell indices (ix, iy) holding map points ``xy`` (..., 2); may lie outside the grid."""
        points = np.asarray(xy, np.float64)
        dx, dy = points[..., 0] - self.origin[0], points[..., 1] - self.origin[1]
        c, s = math.cos(self.yaw), math.sin(self.yaw)
        u, v = c * dx + s * dy, -s * dx + c * dy
        return (np.floor(u / self.resolution).astype(np.int64),
                np.floor(v / self.resolution).astype(np.int64))


def occupancy_grid(scene: Scene, *, resolution: float = 0.1) -> OccupancyGrid:
    """The floor plan seen from above: rooms free, walls and furniture occupied (doors open), outside
    unknown. A margin of one cell surrounds the plan, so its outer walls are drawn whole. An imported
    world's is its own raster (a nav2 map's cells at their resolution and origin, as map_server has them)."""
    if scene.imported:
        return scene.plan
    xmin, ymin, xmax, ymax = scene.bounds
    origin = (xmin - resolution, ymin - resolution)
    cols = int(round((xmax - xmin) / resolution)) + 2
    rows = int(round((ymax - ymin) / resolution)) + 2
    xs = origin[0] + (np.arange(cols) + 0.5) * resolution
    ys = origin[1] + (np.arange(rows) + 0.5) * resolution
    ix, iy = np.floor(xs).astype(np.int64), np.floor(ys).astype(np.int64)
    inside_x, inside_y = (ix >= 0) & (ix < scene.size[0]), (iy >= 0) & (iy < scene.size[1])
    rooms = np.full((rows, cols), -1, np.int64)
    rooms[np.ix_(inside_y, inside_x)] = scene.cell_room[np.ix_(ix[inside_x], iy[inside_y])].T
    cells = np.where(rooms >= 0, FREE, UNKNOWN).astype(np.int8)
    half = resolution / 2 + 1e-9
    for wall in scene.walls:
        if wall.is_lintel:  # a door: the gap under it is open
            continue
        (x0, y0), (x1, y1) = wall.p0, wall.p1
        near_x = (xs >= min(x0, x1) - half) & (xs <= max(x0, x1) + half)
        near_y = (ys >= min(y0, y1) - half) & (ys <= max(y0, y1) + half)
        cells[np.ix_(near_y, near_x)] = OCCUPIED
    for ob in scene.obstacles:
        cells[np.ix_((ys > ob.ymin) & (ys < ob.ymax), (xs > ob.xmin) & (xs < ob.xmax))] = OCCUPIED
    return OccupancyGrid(cells, resolution, origin)
