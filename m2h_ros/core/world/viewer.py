"""Matplotlib pictures of scenes, episodes and camera views (no pyplot state, Agg-safe)."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path

import numpy as np
from matplotlib.axes import Axes
from matplotlib.figure import Figure
from matplotlib.image import imsave
from matplotlib.patches import Polygon, Rectangle

from m2h_ros.core.world.navgrid import HEADING_STEPS
from m2h_ros.core.world.scene import OBSTACLE_COLOR, Scene
from m2h_ros.errors import ConfigError

# Marker per sound category; colour per role (target / distractor).
CATEGORY_MARKERS = {"speech": "o", "music": "^", "background": "s"}
ROLE_COLORS = {"target": "#d62728", "distractor": "#1f1f1f"}


def draw_scene(ax: Axes, scene: Scene, *, sources=None, path=None, labels: bool = True) -> Axes:
    """Top-down plot: room fills, walls, doors, obstacles, grid nodes, sources and an agent path.

    ``sources``: sequence of ``(xy, category)`` or ``(xy, category, role)`` with category in
    CATEGORY_MARKERS and role "target" or "distractor" (default: the first is the target).
    ``path``: sequence of (node, heading) pairs, drawn as a line with heading arrows.
    """
    if scene.imported:
        _draw_plan(ax, scene.plan)
    for room in scene.rooms:
        ax.add_patch(Polygon(room.outline(), closed=True, facecolor=(*room.color, 0.35),
                             edgecolor="none", zorder=0))
        if labels:
            ax.text(*_label_point(room), f"{room.name}\n{room.wall_material}\n{room.floor_material}",
                    ha="center", va="center", fontsize=6, color="#333333", zorder=1)
    for wall in scene.walls:
        xs, ys = (wall.p0[0], wall.p1[0]), (wall.p0[1], wall.p1[1])
        if wall.is_lintel:
            ax.plot(xs, ys, color="#e08a00", lw=1.5, ls=":", zorder=2)
        else:
            ax.plot(xs, ys, color="black", lw=2.5, solid_capstyle="projecting", zorder=2)
    for ob in scene.obstacles:
        ax.add_patch(Rectangle((ob.xmin, ob.ymin), ob.xmax - ob.xmin, ob.ymax - ob.ymin,
                               facecolor=OBSTACLE_COLOR, edgecolor="black", lw=0.5, zorder=2))
    ax.scatter(*scene.grid.positions.T, s=6, color="#777777", zorder=3)
    if sources:
        _draw_sources(ax, sources)
    if path is not None and len(path):
        _draw_path(ax, scene, path)
    xmin, ymin, xmax, ymax = scene.bounds
    ax.set_xlim(xmin - 0.3, xmax + 0.3)
    ax.set_ylim(ymin - 0.3, ymax + 0.3)
    ax.set_aspect("equal")
    ax.set_xlabel("x (m)")
    ax.set_ylabel("y (m)")
    ax.set_title(f"{scene.scene_id}  ({scene.fingerprint()})", fontsize=9)
    return ax


def _label_point(room) -> np.ndarray:
    """A point inside the room for its label: an L room's centroid can lie outside it."""
    if not room.cells:
        from shapely.geometry import Polygon as Shape

        point = Shape(room.polygon).buffer(0).representative_point()
        return np.array([point.x, point.y])
    cells = np.asarray(room.cells, dtype=float) + 0.5
    return cells[np.argmin(((cells - cells.mean(axis=0)) ** 2).sum(axis=1))]


def _draw_plan(ax: Axes, plan) -> None:
    """An imported world's own raster under it: occupied dark, unknown light, free white."""
    rows, cols = plan.cells.shape
    corners = plan.cell_centres(*np.meshgrid(np.arange(cols + 1) - 0.5, np.arange(rows + 1) - 0.5))
    shade = np.where(plan.cells == 0, 1.0, np.where(plan.cells < 0, 0.85, 0.35))
    ax.pcolormesh(corners[..., 0], corners[..., 1], shade, cmap="gray", vmin=0, vmax=1, shading="flat",
                  zorder=-1, rasterized=True)


def _draw_sources(ax: Axes, sources) -> None:
    for index, source in enumerate(sources):
        xy, category = source[0], source[1]
        role = source[2] if len(source) > 2 else ("target" if index == 0 else "distractor")
        if category not in CATEGORY_MARKERS or role not in ROLE_COLORS:
            raise ConfigError(f"source {index}: category {category!r} must be one of "
                              f"{sorted(CATEGORY_MARKERS)} and role {role!r} one of {sorted(ROLE_COLORS)}")
        ax.scatter(*np.asarray(xy, dtype=float)[:2], s=120, marker=CATEGORY_MARKERS[category],
                   color=ROLE_COLORS[role], edgecolor="white", lw=1.0, zorder=5,
                   label=f"{role}: {category}")
    ax.legend(loc="upper right", fontsize=7, framealpha=0.8)


def _draw_path(ax: Axes, scene: Scene, path) -> None:
    steps = np.asarray(path, dtype=np.int64).reshape(-1, 2)
    xy = scene.grid.positions[steps[:, 0]]
    ax.plot(*xy.T, color="#1f77b4", lw=1.5, alpha=0.8, zorder=4)
    arrows = HEADING_STEPS[steps[:, 1]] * 0.3
    ax.quiver(xy[:, 0], xy[:, 1], arrows[:, 0], arrows[:, 1], angles="xy", scale_units="xy", scale=1,
              color=np.linspace(0.2, 1.0, len(steps))[:, None] * np.array([[0.12, 0.47, 0.71]]),
              width=0.006, zorder=4)
    ax.scatter(*xy[0], s=50, marker="D", color="#2ca02c", zorder=5)
    ax.scatter(*xy[-1], s=50, marker="X", color="#1f77b4", zorder=5)


def plot_episode(scene: Scene, *, sources, path, si_sdr=None, out_png) -> Path:
    """Top-down episode picture; with ``si_sdr`` (dB per step, or a mapping label -> dB per step
    for several estimates) a trace subplot beside it."""
    with_trace = si_sdr is not None
    fig = Figure(figsize=(11 if with_trace else 6.5, 5.5), layout="constrained")
    axes = fig.subplots(1, 2, width_ratios=[1.3, 1]) if with_trace else [fig.subplots()]
    draw_scene(axes[0], scene, sources=sources, path=path)
    if with_trace:
        traces = si_sdr if isinstance(si_sdr, Mapping) else {None: si_sdr}
        for label, series in traces.items():
            values = np.asarray(series, dtype=float).reshape(-1)
            axes[1].plot(np.arange(len(values)), values, marker=".", label=label)
        if len(traces) > 1 or None not in traces:
            axes[1].legend(fontsize=8)
        axes[1].set_xlabel("step")
        axes[1].set_ylabel("SI-SDR (dB)")
        axes[1].grid(alpha=0.3)
    out_png = Path(out_png)
    out_png.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out_png, dpi=120)
    return out_png


def save_camera_views(views, out_dir, *, max_depth: float | None = None) -> list[Path]:
    """Save RGB and colour-mapped depth PNGs: ``<name>_rgb.png``, ``<name>_depth.png``.

    ``views``: mapping name -> (rgb, depth), or a sequence of (rgb, depth) named view_000, ...
    Depth maps share one colour scale (0 to ``max_depth``, default: the largest depth seen).
    """
    items = views.items() if isinstance(views, Mapping) else \
        ((f"view_{i:03d}", v) for i, v in enumerate(views))
    items = list(items)
    if not items:
        raise ConfigError("save_camera_views needs at least one (rgb, depth) view")
    vmax = max_depth or max(float(np.max(depth)) for _, (_, depth) in items)
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    written = []
    for name, (rgb, depth) in items:
        imsave(out_dir / f"{name}_rgb.png", np.asarray(rgb, dtype=np.uint8))
        imsave(out_dir / f"{name}_depth.png", np.asarray(depth), cmap="viridis", vmin=0.0, vmax=vmax)
        written += [out_dir / f"{name}_rgb.png", out_dir / f"{name}_depth.png"]
    return written


def camera_strip(views: Sequence, *, titles: Sequence[str] = (), max_depth: float | None = None,
                 out_png) -> Path:
    """One PNG with each view's RGB above its depth on one colour scale (0 to ``max_depth``)."""
    vmax = max_depth or max(float(np.max(depth)) for _, depth in views)
    fig = Figure(figsize=(2.2 * len(views), 4.4), layout="constrained")
    axes = fig.subplots(2, len(views), squeeze=False)
    for i, (rgb, depth) in enumerate(views):
        axes[0, i].imshow(rgb)
        axes[1, i].imshow(depth, cmap="viridis", vmin=0.0, vmax=vmax)
        if i < len(titles):
            axes[0, i].set_title(titles[i], fontsize=8)
        for ax in axes[:, i]:
            ax.set_axis_off()
    out_png = Path(out_png)
    out_png.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out_png, dpi=100)
    return out_png
