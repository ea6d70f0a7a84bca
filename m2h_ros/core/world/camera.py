"""Egocentric RGB + depth camera, rendered exactly from the scene's axis-aligned geometry.

Walls are vertical and axis-aligned and furniture boxes stand on the floor, so each image column is
a vertical plane through the eye: one 2D ray per column finds every wall and box it crosses
(numpy over columns x surfaces). In that plane each surface is a rectangle [t_in, t_out] x [z0, z1]
(t = distance along the optical axis, a wall has t_in = t_out) and every pixel row is a line
z = eye + s * t, so a pixel's depth is the smallest entry depth over the surfaces, floor and
ceiling (slab test). This handles door gaps with lintels (the lintel covers only z >= door height,
so the rows below see through to the next room) and box tops seen from above.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from m2h_ros.core.world.navgrid import heading_angle
from m2h_ros.core.world.scene import OBSTACLE_COLOR, Scene
from m2h_ros.errors import ConfigError

if TYPE_CHECKING:
    from m2h_ros.core.world.mesh_camera import MeshRenderer

_EPS = 1e-9


@dataclass(frozen=True)
class CameraConfig:
    width: int = 128             # pixels
    height: int = 128            # pixels
    hfov_deg: float = 90.0       # horizontal field of view; square pixels set the vertical one
    eye_height: float = 1.5      # metres above the floor, optical axis horizontal
    max_depth: float = 10.0      # depth is clipped to this, metres

    def __post_init__(self) -> None:
        for name in ("width", "height"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or not 1 <= value <= 4096:
                raise ConfigError(f"CameraConfig.{name}={value!r} must be an int in [1, 4096]")
        if not 1.0 <= float(self.hfov_deg) <= 170.0:
            raise ConfigError(f"CameraConfig.hfov_deg={self.hfov_deg!r} must be in [1, 170]")
        if not 0.0 < float(self.eye_height) < 100.0:
            raise ConfigError(f"CameraConfig.eye_height={self.eye_height!r} must be in (0, 100)")
        if not 0.0 < float(self.max_depth) <= 1000.0:
            raise ConfigError(f"CameraConfig.max_depth={self.max_depth!r} must be in (0, 1000]")

    @property
    def focal(self) -> float:
        """Focal length in pixels."""
        return (self.width / 2) / np.tan(np.radians(self.hfov_deg) / 2)


def pixel_slopes(config: CameraConfig) -> tuple[np.ndarray, np.ndarray]:
    """Per column, its offset to the right of the optical axis, and per row, its height above it,
    both per unit of optical depth (pixel centres): what renders a view and what back-projects one."""
    f = config.focal
    return ((np.arange(config.width) + 0.5 - config.width / 2) / f,
            (config.height / 2 - (np.arange(config.height) + 0.5)) / f)


def scene_palette(scene: Scene) -> np.ndarray:
    """Colours (5 (R + 1) + 2, 3) float32 of what the camera shows of a scene with R rooms, in blocks of
    R + 1 rows (row r for room r, the last row for "outside"): walls seen on y = const lines, walls on
    x = const (darker, so corners read), floor, floor checker cells, ceiling; then obstacle sides and tops."""
    colors = np.vstack([np.array([r.color for r in scene.rooms]), [0.35, 0.35, 0.35]])
    floor = 0.55 * colors + 0.45 * 0.35
    return np.vstack([colors, 0.82 * colors, floor, 0.9 * floor, 0.25 * colors + 0.69,
                      OBSTACLE_COLOR, np.multiply(OBSTACLE_COLOR, 1.4)]).astype(np.float32)


class SceneRenderer:
    """Renders views of one scene at arbitrary poses; geometry arrays are built once."""

    def __init__(self, scene: Scene, config: CameraConfig = CameraConfig()) -> None:
        if not isinstance(config, CameraConfig):
            raise ConfigError(f"config must be a CameraConfig, got {type(config).__name__}")
        if config.eye_height >= scene.height:
            raise ConfigError(f"CameraConfig.eye_height={config.eye_height} is not below the "
                              f"ceiling of scene {scene.scene_id} ({scene.height} m)")
        self.scene, self.config = scene, config
        walls = scene.walls
        # Walls: the constant coordinate, its axis (0: x = c), extent along the wall, z range.
        self._wall_axis = np.array([0 if w.p0[0] == w.p1[0] else 1 for w in walls], dtype=np.int64)
        self._wall_c = np.array([w.p0[a] for w, a in zip(walls, self._wall_axis)], dtype=np.float64)
        self._wall_lo = np.array([w.p0[1 - a] for w, a in zip(walls, self._wall_axis)], dtype=np.float64)
        self._wall_hi = np.array([w.p1[1 - a] for w, a in zip(walls, self._wall_axis)], dtype=np.float64)
        self._wall_rooms = np.array([w.rooms for w in walls], dtype=np.int64).reshape(-1, 2)
        boxes = scene.obstacles
        self._boxes = np.array([[o.xmin, o.ymin, o.xmax, o.ymax] for o in boxes],
                               dtype=np.float64).reshape(-1, 4)
        self._z0 = np.concatenate([[w.z0 for w in walls], np.zeros(len(boxes))])
        self._z1 = np.concatenate([[w.z1 for w in walls], [o.height for o in boxes]])
        self._full_height = np.concatenate([(self._z0[:len(walls)] <= 0) & (self._z1[:len(walls)] >= scene.height),
                                            np.zeros(len(boxes), dtype=bool)])
        self._palette = scene_palette(scene)
        self._n_block = len(scene.rooms) + 1
        # Pixel geometry: column offsets (right of the axis) and row slopes (up), in units of focal.
        self._col_offset, self._row_slope = pixel_slopes(config)

    def render(self, xy, angle: float) -> tuple[np.ndarray, np.ndarray]:
        """RGB (H, W, 3) uint8 and depth (H, W) float32 metres along the optical axis."""
        cfg, scene = self.config, self.scene
        origin = np.asarray(xy, dtype=np.float64)[:2]
        forward = np.array([np.cos(angle), np.sin(angle)])
        right = np.array([forward[1], -forward[0]])
        # Ray of each column with unit forward component: its parameter t is the optical depth.
        dirs = forward + self._col_offset[:, None] * right                  # (W, 2)
        t_in, t_out = self._column_hits(origin, dirs)                       # (W, S)
        # A full-height wall hides everything behind it; keep the K nearest surfaces per column.
        blocked = np.where(self._full_height, t_in, np.inf).min(axis=1, keepdims=True)
        t_in = np.where(t_in <= blocked + 1e-6, t_in, np.inf)
        k = max(1, int(np.isfinite(t_in).sum(axis=1).max()))
        order = np.argsort(t_in, axis=1)[:, :k]                             # (W, K)
        t_in = np.take_along_axis(t_in, order, 1)
        t_out = np.take_along_axis(t_out, order, 1)
        z0, z1 = self._z0[order], self._z1[order]
        # Slab test in each column plane: the row's line z = eye + s t inside [z0, z1].
        s = self._row_slope[:, None, None]                                  # (H, 1, 1)
        with np.errstate(divide="ignore", invalid="ignore"):
            za, zb = (z0 - cfg.eye_height) / s, (z1 - cfg.eye_height) / s  # (H, W, K)
            entry = np.maximum(t_in, np.minimum(za, zb))
            exit_ = np.minimum(t_out, np.maximum(za, zb))
            surface_depth = np.where(entry <= exit_, entry, np.inf)
            plane_depth = np.where(s[:, :, 0] < 0, -cfg.eye_height / s[:, :, 0],
                                   (scene.height - cfg.eye_height) / s[:, :, 0])  # (H, 1)
        plane_depth = np.broadcast_to(plane_depth, (cfg.height, cfg.width))
        nearest = surface_depth.argmin(axis=2)                              # (H, W)
        columns = np.arange(cfg.width)
        near_depth = surface_depth[np.arange(cfg.height)[:, None], columns, nearest]
        on_plane = plane_depth <= near_depth
        depth = np.where(on_plane, plane_depth, near_depth)
        # Palette index per pixel: the nearest surface's colour, +1 where a box is seen from above.
        surface_color = self._surface_palette(origin, order)                # (W, K)
        from_top = near_depth > t_in[columns, nearest] + 1e-9
        color = surface_color[columns, nearest] + from_top
        color = np.where(on_plane, self._plane_palette(origin, dirs, depth), color)
        shade = (0.35 + 0.65 * np.exp(-depth / 8.0)).astype(np.float32)
        rgb8 = (np.minimum(self._palette[color] * (shade[..., None] * 255.0), 255.0) + 0.5).astype(np.uint8)
        return rgb8, np.minimum(depth, cfg.max_depth).astype(np.float32)

    def render_node(self, node: int, heading: int) -> tuple[np.ndarray, np.ndarray]:
        return self.render(self.scene.grid.positions[node], float(heading_angle(heading)))

    def _column_hits(self, origin: np.ndarray, dirs: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Entry/exit depth (W, S) of each column ray through each wall and box; inf = missed."""
        axis = self._wall_axis
        with np.errstate(divide="ignore", invalid="ignore"):
            t_wall = (self._wall_c - origin[axis]) / dirs[:, axis]          # (W, Sw)
            along = origin[1 - axis] + t_wall * dirs[:, 1 - axis]
            hit = (t_wall > _EPS) & (along >= self._wall_lo - 1e-9) & (along <= self._wall_hi + 1e-9)
            t_wall = np.where(hit, t_wall, np.inf)
            lo = (self._boxes[:, :2] - origin) / dirs[:, None, :]           # (W, B, 2)
            hi = (self._boxes[:, 2:] - origin) / dirs[:, None, :]
            box_in = np.nan_to_num(np.minimum(lo, hi), nan=-np.inf).max(axis=2)
            box_out = np.nan_to_num(np.maximum(lo, hi), nan=np.inf).min(axis=2)
        box_hit = (box_in <= box_out) & (box_in > _EPS)
        box_in = np.where(box_hit, box_in, np.inf)
        return np.hstack([t_wall, box_in]), np.hstack([t_wall, np.where(box_hit, box_out, np.inf)])

    def _surface_palette(self, origin: np.ndarray, order: np.ndarray) -> np.ndarray:
        """Palette row (W, K) of each column's candidate surfaces; walls show the camera's side."""
        n_walls, n = len(self._wall_axis), self._n_block
        wall = np.minimum(order, max(n_walls - 1, 0))
        axis = self._wall_axis[wall]
        facing = (origin[axis] > self._wall_c[wall]).astype(np.int64)
        room = self._wall_rooms[wall, facing]
        room = np.where(room >= 0, room, n - 1)
        return np.where(order >= n_walls, 5 * n, room + n * (axis == 0))

    def _plane_palette(self, origin: np.ndarray, dirs: np.ndarray, depth: np.ndarray) -> np.ndarray:
        """Palette row (H, W) of floor (below the horizon) or ceiling at each pixel's hit point."""
        finite_depth = np.where(np.isfinite(depth), depth, 0.0)             # horizon row of odd H
        cells = np.floor(origin + finite_depth[..., None] * dirs).astype(np.int64)   # (H, W, 2)
        w, h = self.scene.size
        ix, iy = cells[..., 0], cells[..., 1]
        inside = (ix >= 0) & (ix < w) & (iy >= 0) & (iy < h)
        room = np.where(inside, self.scene.cell_room[np.clip(ix, 0, w - 1), np.clip(iy, 0, h - 1)],
                        self._n_block - 1)
        n = self._n_block
        floor_block = np.where((ix + iy) % 2 == 0, 3 * n, 2 * n)           # checker: motion cue
        return room + np.where((self._row_slope < 0)[:, None], floor_block, 4 * n)


class CameraViews:
    """Per-scene cache of the views at the discrete poses (node, heading), rendered lazily. A world with a
    triangle mesh (``scene.mesh``, e.g. loaded from a robot's map or a scan) is seen through the mesh
    camera; a generated scene through the exact renderer."""

    def __init__(self, scene: Scene, config: CameraConfig = CameraConfig()) -> None:
        mesh = getattr(scene, "mesh", None)
        if mesh is None:
            self.renderer: SceneRenderer | MeshRenderer = SceneRenderer(scene, config)
        else:
            from m2h_ros.core.world.mesh_camera import MeshRenderer   # it imports this module

            self.renderer = MeshRenderer(mesh, config, floor_z=getattr(scene, "floor_z", 0.0))
        self.scene, self.config = scene, config
        n = scene.grid.n_nodes
        self._rendered = np.zeros((n, 4), dtype=bool)
        self._rgb: np.ndarray | None = None
        self._depth: np.ndarray | None = None

    def views(self, nodes, headings) -> tuple[np.ndarray, np.ndarray]:
        """RGB (B, H, W, 3) uint8 and depth (B, H, W) float32 for arrays of nodes and headings."""
        nodes = np.asarray(nodes, dtype=np.int64).reshape(-1)
        cfg = self.config
        rgb = np.empty((len(nodes), cfg.height, cfg.width, 3), np.uint8)
        depth = np.empty((len(nodes), cfg.height, cfg.width), np.float32)
        self.copy_views(nodes, headings, rgb, depth, range(len(nodes)))
        return rgb, depth

    def copy_views(self, nodes, headings, rgb: np.ndarray, depth: np.ndarray, rows) -> None:
        """Write the views of (nodes[i], headings[i]) into rgb[rows[i]] and depth[rows[i]] (one copy
        each: a batch gathered with a fancy index and then scattered would copy every image twice)."""
        nodes = np.asarray(nodes, dtype=np.int64).reshape(-1)
        headings = np.asarray(headings, dtype=np.int64).reshape(-1)
        if nodes.shape != headings.shape:
            raise ConfigError(f"nodes {nodes.shape} and headings {headings.shape} differ in shape")
        n = self.scene.grid.n_nodes
        if nodes.size and (nodes.min() < 0 or nodes.max() >= n or headings.min() < 0 or headings.max() > 3):
            raise ConfigError(f"node must be in [0, {n}) and heading in [0, 4) "
                              f"(got nodes {nodes.tolist()}, headings {headings.tolist()})")
        self._ensure(nodes, headings)
        for row, node, heading in zip(rows, nodes.tolist(), headings.tolist()):
            rgb[row], depth[row] = self._rgb[node, heading], self._depth[node, heading]

    def view(self, node: int, heading: int) -> tuple[np.ndarray, np.ndarray]:
        rgb, depth = self.views([node], [heading])
        return rgb[0], depth[0]

    def prerender(self) -> None:
        """Render every pose now (e.g. before timing or forking workers)."""
        nodes, headings = np.nonzero(~self._rendered)
        self._ensure(nodes, headings)

    def _ensure(self, nodes: np.ndarray, headings: np.ndarray) -> None:
        if self._rgb is None:
            cfg, n = self.config, self.scene.grid.n_nodes
            self._rgb = np.zeros((n, 4, cfg.height, cfg.width, 3), dtype=np.uint8)
            self._depth = np.zeros((n, 4, cfg.height, cfg.width), dtype=np.float32)
        missing = ~self._rendered[nodes, headings]
        for node, heading in set(zip(nodes[missing].tolist(), headings[missing].tolist())):
            self._rgb[node, heading], self._depth[node, heading] = self.renderer.render(
                self.scene.grid.positions[node], float(heading_angle(heading)))
            self._rendered[node, heading] = True
