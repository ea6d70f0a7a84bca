"""Egocentric RGB + depth camera on any triangle mesh, and a generated scene as such a mesh.

``MeshRenderer`` casts one ray per pixel with Embree (``raycast.RayCaster``) and keeps the conventions
of ``camera.SceneRenderer``: eye ``eye_height`` above the floor, optical axis horizontal, depth along
the optical axis clipped to ``max_depth``, colour = surface colour times the same distance shading. It
renders worlds that were not generated (a robot's map extruded to walls, a scanned mesh).

``scene_mesh`` turns a generated scene into triangles in the colours ``SceneRenderer`` shows, so the
mesh camera reproduces the exact camera on it (tested) and the scene can be exported as a mesh.
"""

from __future__ import annotations

import math

import numpy as np

from m2h_ros.core.world.camera import CameraConfig, pixel_slopes, scene_palette
from m2h_ros.core.world.raycast import RayCaster, TriangleMesh
from m2h_ros.core.world.scene import Scene
from m2h_ros.errors import ConfigError

# Colour of a pixel whose ray leaves the mesh (its depth reads max_depth).
BACKGROUND_COLOR = (0.0, 0.0, 0.0)
# A zero-thickness wall shows each room its own colour: one quad per side, this far (metres) toward the
# room it faces, so a ray meets its own side first. Depth moves by it over the cosine of incidence.
WALL_SIDE_OFFSET = 1e-4


class MeshRenderer:
    """Renders views of one triangle mesh at arbitrary poses; the ray caster and pixel rays are built once."""

    def __init__(self, mesh: TriangleMesh, config: CameraConfig = CameraConfig(), *, floor_z: float = 0.0) -> None:
        if not isinstance(config, CameraConfig):
            raise ConfigError(f"config must be a CameraConfig, got {type(config).__name__}")
        if not isinstance(mesh, TriangleMesh):
            raise ConfigError(f"mesh must be a raycast.TriangleMesh, got {type(mesh).__name__}")
        if not math.isfinite(float(floor_z)):
            raise ConfigError(f"floor_z={floor_z!r} must be a finite height in metres")
        self.mesh, self.config = mesh, config
        self.eye_z = float(floor_z) + float(config.eye_height)
        self._caster = RayCaster(mesh)
        # Face colours with the background as row -1, so a miss (face -1) needs no special case.
        self._colors = np.vstack([mesh.face_colors, BACKGROUND_COLOR]).astype(np.float32)
        # Pixel rays with a unit forward component, so Embree's hit distance is the optical depth. Per
        # frame only the horizontal part turns: (x, y) = forward + offset * right, per column.
        col_offset, row_slope = pixel_slopes(config)
        self._col_offset = col_offset.astype(np.float32)
        self._rays = np.empty((config.height, config.width, 3), np.float32)
        self._rays[..., 2] = row_slope.astype(np.float32)[:, None]

    def render(self, xy, angle: float) -> tuple[np.ndarray, np.ndarray]:
        """RGB (H, W, 3) uint8 and depth (H, W) float32 metres along the optical axis."""
        cfg = self.config
        x, y = (float(v) for v in np.asarray(xy, dtype=np.float64)[:2])
        cos, sin = np.float32(np.cos(angle)), np.float32(np.sin(angle))
        rays = self._rays.copy()                           # per frame: renders may run on several threads
        rays[..., 0] = cos + self._col_offset * sin        # right = (sin, -cos): clockwise from forward
        rays[..., 1] = sin - self._col_offset * cos
        distance, face = self._caster.cast((x, y, self.eye_z), rays.reshape(-1, 3))
        distance = distance.astype(np.float32).reshape(cfg.height, cfg.width)
        # SceneRenderer's shading and rounding, in place on float32 (a tenth of the frame's time otherwise).
        shade = np.exp(distance / np.float32(-8.0))
        shade *= 0.65
        shade += 0.35
        shade *= 255.0
        rgb = np.take(self._colors, face, axis=0).reshape(cfg.height, cfg.width, 3)   # 4x a fancy index's speed
        rgb *= shade[..., None]
        np.minimum(rgb, 255.0, out=rgb)
        rgb += 0.5
        return rgb.astype(np.uint8), np.minimum(distance, np.float32(cfg.max_depth))


def scene_mesh(scene: Scene) -> TriangleMesh:
    """The generated scene's walls, lintels, floor, ceiling and furniture boxes as triangles in the colours
    ``SceneRenderer`` shows; parts name the surface and its material ("wall:brickwork", "floor:carpet_thin",
    "ceiling:...", "obstacle:..."). Each wall side is its own quad, normals face the room they show."""
    palette = scene_palette(scene)
    n_block = len(scene.rooms) + 1
    builder = _QuadBuilder()
    for wall in scene.walls:
        axis = 0 if wall.p0[0] == wall.p1[0] else 1     # 0: the wall lies on x = const
        const, lo, hi = wall.p0[axis], wall.p0[1 - axis], wall.p1[1 - axis]
        for side, room in zip((-1, 1), wall.rooms):
            # Reaching past the ends by the offset closes the gap where two walls' quads meet at a corner.
            c, a, b = const + side * WALL_SIDE_OFFSET, lo - WALL_SIDE_OFFSET, hi + WALL_SIDE_OFFSET
            ends = [(c, a), (c, b)] if axis == 0 else [(a, c), (b, c)]
            if (side < 0) == (axis == 0):               # wind so the normal points toward this side
                ends.reverse()
            (x0, y0), (x1, y1) = ends
            color = palette[(room if room >= 0 else n_block - 1) + n_block * (axis == 0)]
            builder.add([(x0, y0, wall.z0), (x1, y1, wall.z0), (x1, y1, wall.z1), (x0, y0, wall.z1)],
                        color, f"wall:{wall.material}")
    for index, room in enumerate(scene.rooms):
        for ix, iy in room.cells:
            checker = 3 if (ix + iy) % 2 == 0 else 2      # the floor checker of SceneRenderer
            builder.add([(ix, iy, 0.0), (ix + 1, iy, 0.0), (ix + 1, iy + 1, 0.0), (ix, iy + 1, 0.0)],
                        palette[index + checker * n_block], f"floor:{room.floor_material}")
            top = scene.height
            builder.add([(ix, iy, top), (ix, iy + 1, top), (ix + 1, iy + 1, top), (ix + 1, iy, top)],
                        palette[index + 4 * n_block], f"ceiling:{room.ceiling_material}")
    side_color, top_color = palette[5 * n_block], palette[5 * n_block + 1]
    for box in scene.obstacles:
        part, h = f"obstacle:{box.material}", box.height
        corners = [(box.xmin, box.ymin), (box.xmax, box.ymin), (box.xmax, box.ymax), (box.xmin, box.ymax)]
        for (x0, y0), (x1, y1) in zip(corners, corners[1:] + corners[:1]):   # counter-clockwise: outward
            builder.add([(x0, y0, 0.0), (x1, y1, 0.0), (x1, y1, h), (x0, y0, h)], side_color, part)
        builder.add([(x, y, h) for x, y in corners], top_color, part)
    return builder.mesh()


class _QuadBuilder:
    """Collects planar quads (corners counter-clockwise seen from the side the normal points to)."""

    def __init__(self) -> None:
        self._corners: list[list[tuple[float, float, float]]] = []
        self._colors: list[np.ndarray] = []
        self._parts: list[int] = []
        self._part_index: dict[str, int] = {}

    def add(self, corners, color, part: str) -> None:
        self._corners.append(corners)
        self._colors.append(color)
        self._parts.append(self._part_index.setdefault(part, len(self._part_index)))

    def mesh(self) -> TriangleMesh:
        n = len(self._corners)
        quad = np.arange(4 * n).reshape(n, 4)
        faces = np.stack([quad[:, [0, 1, 2]], quad[:, [0, 2, 3]]], axis=1).reshape(-1, 3)
        return TriangleMesh(vertices=np.asarray(self._corners, np.float64).reshape(-1, 3), faces=faces,
                            face_colors=np.repeat(np.asarray(self._colors, np.float32), 2, axis=0),
                            face_part=np.repeat(self._parts, 2), parts=tuple(self._part_index))
