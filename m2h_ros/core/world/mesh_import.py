"""Worlds from meshes made elsewhere: a scan (Replica, HM3D, Matterport3D) or an export from Blender
or Gazebo (glTF/GLB, OBJ, PLY) read into a TriangleMesh (metres, z up), its floor plan found by casting
rays, and its parts named, so that a material map can give imported walls acoustic materials.

The floor plan casts rays only, so it works on open scans (single-sided surfaces, holes) and on closed
box models alike. Straight down through every cell centre it lists every surface in the column; the
upward-facing ones cluster into floor levels. A cell is free when its floor lies at the chosen level and
nothing stands between a step's height and the robot's head room above it. Walls are vertical, so the
down-casts miss them: horizontal rays from each floor cell at a few heights find them, and a cell whose
horizontal rays mostly hit surfaces from behind is inside something solid (a box wall seen from within).
"""

from __future__ import annotations

import difflib
import fnmatch
import math
import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from m2h_ros.core.world.frames import FREE, OCCUPIED, UNKNOWN, OccupancyGrid
from m2h_ros.core.world.raycast import RayCaster, TriangleMesh
from m2h_ros.errors import ConfigError

UNITS = {"mm": 0.001, "cm": 0.01, "m": 1.0, "in": 0.0254, "ft": 0.3048}  # metres per mesh unit
UNIT_NAMES = {"mm": "millimetres", "cm": "centimetres", "m": "metres", "in": "inches", "ft": "feet"}
UP_AXIS_DEFAULT = {".glb": "y", ".gltf": "y", ".obj": "z", ".ply": "z"}  # glTF is y-up by its specification
# Rotation taking a y-up mesh to z-up (x stays, y becomes z, z becomes -y), as Blender imports glTF.
Y_UP_TO_Z_UP = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]])
MID_GREY = 0.5
BUILDING_EXTENT = (1.0, 500.0)  # metres across: a mesh outside this range is in other units
TYPICAL_EXTENT = 10.0           # metres: the units guess takes the size nearest this

UP_FACING = 0.7         # a floor's normal points up within 45 degrees
LAYER_SKIP = 1e-3       # metres: a down-cast goes on this far below the surface it hit
MAX_LAYERS = 128        # surfaces listed per column at most
LEVEL_BIN = 0.02        # metres: histogram bin of floor heights
MIN_LEVEL_AREA = 1.0    # m^2 of open floor that makes a level
MAX_CELLS = 16_000_000  # a plan larger than this asks for a coarser resolution
RAY_SPACING = 0.35      # metres between the heights of the horizontal rays
# Horizontal ray directions, every 45 degrees from +x (even entries: along the axes).
COMPASS = np.array([[math.cos(a), math.sin(a), 0.0] for a in np.arange(8) * math.pi / 4]).round(12)


# ----------------------------------------------------------------------------- reading


def read_mesh(path: str | Path, *, units: str | float = "m", up_axis: str | None = None) -> TriangleMesh:
    """Read a glTF/GLB, OBJ or PLY mesh into one TriangleMesh in metres with z up.

    A scene's geometries are flattened with their node transforms. Parts: one per glTF node (and
    material), OBJ object/group (and material), one for a PLY; a part with a named material is called
    ``"node/material"``. Face colours (display sRGB in [0, 1]) come from vertex colours averaged over the
    face, else the material's texture at the face's UV centroid, else its base colour, else mid grey.
    ``units``: metres per mesh unit, or one of mm, cm, m, in, ft. ``up_axis``: "y" or "z"; by default y
    for glTF (its specification's convention) and z for OBJ and PLY.
    """
    path = Path(path)
    scale = _unit_scale(units)
    suffix = path.suffix.lower()
    if suffix not in UP_AXIS_DEFAULT:
        raise ConfigError(f"{path}: cannot read '{suffix}' meshes; export it as one of "
                          f"{', '.join(UP_AXIS_DEFAULT)} (Blender and trimesh convert)")
    up = UP_AXIS_DEFAULT[suffix] if up_axis is None else up_axis
    if up not in ("y", "z"):
        raise ConfigError(f"up_axis={up_axis!r} must be 'y' or 'z'")
    if not path.is_file():
        raise ConfigError(f"mesh file {path} does not exist")
    vertices, faces, colors, face_part, parts = _flatten(_load_scene(path, suffix), path, suffix)
    if not len(faces):
        raise ConfigError(f"{path} holds no triangles (only points or lines, or an empty scene)")
    if up == "y":
        vertices = vertices @ Y_UP_TO_Z_UP.T
    vertices = vertices * scale
    _check_extent(vertices, path, units, scale)
    return TriangleMesh(vertices, faces, colors, face_part, parts)


def _unit_scale(units: str | float) -> float:
    if isinstance(units, str):
        if units not in UNITS:
            raise ConfigError(f"units={units!r} must be one of {', '.join(UNITS)} or metres per mesh unit")
        return UNITS[units]
    if isinstance(units, bool) or not isinstance(units, (int, float)) or not 0 < float(units) < math.inf:
        raise ConfigError(f"units={units!r} must be one of {', '.join(UNITS)} or a positive number "
                          "(metres per mesh unit)")
    return float(units)


def _load_scene(path: Path, suffix: str):
    import trimesh  # here and below: 0.6 s to import, paid only by what reads a mesh

    # OBJ: one geometry per object, group and material, so parts keep the names the modeller gave.
    options = {"split_objects": True, "split_groups": True} if suffix == ".obj" else {}
    try:
        return trimesh.load_scene(path, process=False, **options)
    except Exception as err:  # a parser of arbitrary files fails in arbitrary ways
        raise ConfigError(f"cannot read {path} as a {suffix[1:].upper()} mesh (corrupt or truncated?): "
                          f"{type(err).__name__}: {err}") from err


def _flatten(scene, path: Path, suffix: str):
    """Vertices, faces, face colours, face parts and part names of every triangle geometry in world
    coordinates (mesh units, the file's up axis)."""
    import trimesh

    gltf = suffix in (".glb", ".gltf")
    vertices, faces, colors, face_part = [], [], [], []
    parts: dict[str, int] = {}
    offset = 0
    for node in scene.graph.nodes_geometry:
        transform, geometry_name = scene.graph[node]
        geometry = scene.geometry[geometry_name]
        if not isinstance(geometry, trimesh.Trimesh) or not len(geometry.faces):
            continue
        transform = np.asarray(transform, np.float64)
        local = np.asarray(geometry.faces, np.int64)
        if np.linalg.det(transform[:3, :3]) < 0:  # a mirroring node turns its triangles inside out
            local = local[:, ::-1]
        vertices.append(np.asarray(geometry.vertices, np.float64) @ transform[:3, :3].T + transform[:3, 3])
        faces.append(local + offset)
        offset += len(geometry.vertices)
        colors.append(_face_colors(geometry, gltf=gltf))
        part = parts.setdefault(_part_name(scene, node, geometry, path, suffix), len(parts))
        face_part.append(np.full(len(local), part, np.int64))
    if not faces:
        return np.zeros((0, 3)), np.zeros((0, 3), np.int64), np.zeros((0, 3), np.float32), None, ()
    return (np.concatenate(vertices), np.concatenate(faces), np.concatenate(colors),
            np.concatenate(face_part), tuple(parts))


def _part_name(scene, node: str, geometry, path: Path, suffix: str) -> str:
    name = node
    parent = scene.graph.transforms.parents.get(node)
    # trimesh hangs each primitive of a multi-primitive glTF mesh under its node as "<node>_<6 hex digits>"
    # (random): the node's own name is the stable one.
    if parent is not None and re.fullmatch(re.escape(parent) + r"_[0-9a-f]{6}", node):
        name = parent
    material = getattr(getattr(geometry.visual, "material", None), "name", None)
    # trimesh appends the material to an OBJ geometry's name when the file uses several.
    if suffix == ".obj" and material and name.endswith(f"_{material}"):
        name = name[: -len(material) - 1]
    name = name or path.name
    return f"{name}/{material}" if material else name


def _face_colors(geometry, *, gltf: bool) -> np.ndarray:
    """(F, 3) float32 display colours of a trimesh geometry's faces.

    glTF: base colour factor x texture x COLOR_0, multiplied in linear light as its specification says.
    OBJ and PLY: vertex colours, else the texture (map_Kd; exporters leave Kd at a default grey beside
    it), else the diffuse colour Kd."""
    from trimesh.visual.color import to_rgba, uv_to_color

    visual, faces = geometry.visual, np.asarray(geometry.faces)
    if visual.kind == "face":
        return (np.asarray(visual.face_colors, np.float64)[:, :3] / 255).astype(np.float32)
    # trimesh keeps a glTF primitive's COLOR_0 beside its material as a vertex attribute
    painted = visual.vertex_colors if visual.kind == "vertex" else getattr(visual, "vertex_attributes", {}).get("color")
    vertex = None
    if painted is not None and len(painted) == len(geometry.vertices):
        vertex = to_rgba(painted)[:, :3].astype(np.float64)[faces].mean(axis=1) / 255
    material = getattr(visual, "material", None) if visual.kind == "texture" else None
    factor = getattr(material, "baseColorFactor" if gltf else "diffuse", None)
    factor = None if factor is None else np.asarray(factor, np.float64)[:3] / 255
    image = getattr(material, "baseColorTexture" if gltf else "image", None)
    uv = getattr(visual, "uv", None)
    texel = None
    if image is not None and uv is not None and len(uv) == len(geometry.vertices):
        texel = uv_to_color(np.asarray(uv, np.float64)[faces].mean(axis=1), image)[:, :3] / 255
    if gltf:
        terms = [term for term in (factor, None if texel is None else _srgb_to_linear(texel), vertex)
                 if term is not None]
        rgb = _linear_to_srgb(np.prod(np.broadcast_arrays(*terms, np.ones((len(faces), 3))), axis=0)) \
            if terms else None
    else:
        rgb = next((term for term in (vertex, texel, factor) if term is not None), None)
    if rgb is None:
        return np.full((len(faces), 3), MID_GREY, np.float32)
    return np.broadcast_to(rgb, (len(faces), 3)).astype(np.float32)


def _linear_to_srgb(c: np.ndarray) -> np.ndarray:
    c = np.clip(c, 0.0, 1.0)
    return np.where(c <= 0.0031308, 12.92 * c, 1.055 * c ** (1 / 2.4) - 0.055)


def _srgb_to_linear(c: np.ndarray) -> np.ndarray:
    c = np.clip(c, 0.0, 1.0)
    return np.where(c <= 0.04045, c / 12.92, ((c + 0.055) / 1.055) ** 2.4)


def _check_extent(vertices: np.ndarray, path: Path, units: str | float, scale: float) -> None:
    """A building is 1-500 m across; outside that the mesh is in other units than ``units`` says."""
    extent = float(np.ptp(vertices[:, :2], axis=0).max())
    low, high = BUILDING_EXTENT
    if low <= extent <= high:
        return
    raw = extent / scale
    seen = f"{path} is {extent:.4g} m across with units={units!r}"
    fits = {unit: raw * metres for unit, metres in UNITS.items() if unit != units and low <= raw * metres <= high}
    if fits:
        guess = min(fits, key=lambda unit: abs(math.log(fits[unit] / TYPICAL_EXTENT)))
        others = "".join(f"; in {unit}: {size:.3g} m" for unit, size in fits.items() if unit != guess)
        raise ConfigError(f"{seen}; it looks like {UNIT_NAMES[guess]}: pass units={guess} "
                          f"({fits[guess]:.3g} m across{others})")
    size = "wide" if extent > high else "small"
    raise ConfigError(f"{seen}, too {size} for a building; pass units=<metres per mesh unit> "
                      f"({', '.join(UNITS)} or a number)")


# ----------------------------------------------------------------------------- floor plan


@dataclass(frozen=True)
class FloorLevel:
    z: float             # floor height, metres
    area: float          # m^2 of floor at this height with head room above it
    roofed_area: float   # m^2 of that with something above the head room (a ceiling): 0 on a flat roof


@dataclass(frozen=True, eq=False)
class MeshPlan:
    """The floor plan of one level of a mesh."""
    grid: OccupancyGrid                # yaw 0, origin one cell beyond the mesh's x/y minimum
    floor_z: float                     # the level's floor height, metres
    ceiling_z: float | None            # median ceiling over the free cells; None when most are open above
    levels: tuple[FloorLevel, ...]     # every level found, lowest first
    level: int                         # index into ``levels`` of the one planned

    @property
    def ceiling_height(self) -> float | None:
        return None if self.ceiling_z is None else self.ceiling_z - self.floor_z


@dataclass(frozen=True)
class _Columns:
    """Every surface the straight down-casts crossed: hit i lies in column ``col[i]`` at height ``z[i]``."""
    col: np.ndarray
    z: np.ndarray
    up: np.ndarray  # the surface faces up (a floor or a top), seen from its front


def mesh_floor_plan(mesh: TriangleMesh, *, resolution: float = 0.05, head_room: float = 1.8,
                    step_height: float = 0.15, floor_level: int | None = None,
                    caster: RayCaster | None = None) -> MeshPlan:
    """Floor plan of a mesh (metres, z up) at one floor level: FREE where the floor lies within
    ``step_height`` of the level and nothing stands between ``step_height`` and ``head_room`` above it,
    OCCUPIED where something does (walls, furniture), UNKNOWN where there is no floor at that level.

    Levels are the heights where upward-facing surfaces with head room above them cluster (two storeys
    give two, a flat roof one more). ``floor_level`` indexes them from the lowest; by default the level
    with the most floor under a ceiling (the largest floor if nothing has a ceiling). ``caster``: a
    RayCaster already built on ``mesh``, to skip building another.
    """
    _check_plan_options(resolution, head_room, step_height)
    if caster is None:
        caster = RayCaster(mesh)
    elif caster.mesh is not mesh:
        raise ConfigError("mesh_floor_plan's caster was built on another mesh")
    low, high = mesh.bounds
    cols = int(math.ceil((high[0] - low[0]) / resolution)) + 2
    rows = int(math.ceil((high[1] - low[1]) / resolution)) + 2
    if rows * cols > MAX_CELLS:
        raise ConfigError(f"a {cols} x {rows} cell plan at resolution={resolution} m is too large; "
                          f"pass a coarser resolution")
    grid = OccupancyGrid(np.full((rows, cols), UNKNOWN, np.int8), resolution,
                         (float(low[0]) - resolution, float(low[1]) - resolution))
    iy, ix = np.divmod(np.arange(rows * cols), cols)
    xy = grid.cell_centres(ix, iy)
    columns = _survey_columns(caster, xy, top=float(high[2]) + 1.0)
    levels = _find_levels(columns, len(xy), resolution=resolution, head_room=head_room, step_height=step_height)
    if not levels:
        size = high - low
        raise ConfigError(f"no floor found in a mesh of {size[0]:.3g} x {size[1]:.3g} x {size[2]:.3g} m: no "
                          f"upward-facing surface of {MIN_LEVEL_AREA} m^2 or more has {head_room} m of head "
                          "room above it (a y-up mesh read as z-up stands on its side: pass up_axis='y'; "
                          "a floor's triangles must face up)")
    level = _choose_level(levels, floor_level)
    floor_z = levels[level].z
    floor = _cell_floors(columns, len(xy), floor_z, step_height)
    has_floor = np.isfinite(floor)
    base = np.where(has_floor, floor, floor_z)
    # A column without floor at this level is occupied if anything lies at the level: a box wall's bottom
    # face hides the floor face it stands on (coplanar), but outside the building there is nothing.
    lowest = np.where(has_floor, step_height, -step_height)
    blocked, ceiling = _column_obstacles(columns, base, lowest, head_room=head_room)
    cells = np.full(len(xy), UNKNOWN, np.int8)
    cells[has_floor] = FREE
    cells[blocked] = OCCUPIED
    open_floor = np.flatnonzero(cells == FREE)
    cells[_walls_near(caster, grid, xy, base, open_floor, step_height=step_height, head_room=head_room)] = OCCUPIED
    above = ceiling[cells == FREE]
    roofed = np.isfinite(above)
    ceiling_z = float(np.median(above[roofed])) if roofed.sum() * 2 > max(above.size, 1) else None
    return MeshPlan(OccupancyGrid(cells.reshape(rows, cols), resolution, grid.origin), floor_z, ceiling_z,
                    tuple(levels), level)


def _check_plan_options(resolution: float, head_room: float, step_height: float) -> None:
    if not 0.005 <= float(resolution) <= 1.0:
        raise ConfigError(f"resolution={resolution!r} must be in [0.005, 1] metres per cell")
    if not 0.0 < float(step_height) < float(head_room) <= 10.0:
        raise ConfigError(f"step_height={step_height!r} and head_room={head_room!r} must satisfy "
                          "0 < step_height < head_room <= 10 metres")


def _survey_columns(caster: RayCaster, xy: np.ndarray, *, top: float) -> _Columns:
    """Cast straight down from ``top`` through every column, again and again from just below each hit,
    until every column has run out of surfaces (one cast per layer, over the columns still going)."""
    normal_z = caster.mesh.normals[:, 2]
    z = np.full(len(xy), top)
    active = np.arange(len(xy))
    col, height, up = [], [], []
    for _ in range(MAX_LAYERS):
        if not active.size:
            break
        origins = np.column_stack([xy[active], z[active]])
        distance, face = caster.cast(origins, np.broadcast_to((0.0, 0.0, -1.0), origins.shape))
        hit = face >= 0
        active = active[hit]
        z[active] -= distance[hit]
        col.append(active)
        height.append(z[active].copy())
        up.append(normal_z[face[hit]] >= UP_FACING)
        z[active] -= LAYER_SKIP
    return _Columns(np.concatenate(col), np.concatenate(height), np.concatenate(up))


def _find_levels(columns: _Columns, n_cells: int, *, resolution: float, head_room: float,
                 step_height: float) -> list[FloorLevel]:
    """Heights where upward-facing surfaces with head room above them cluster, lowest first.

    Greedy peaks of a histogram of floor heights (each column counted once per bin): the fullest
    window of +-``step_height`` is a level if enough of it has head room, and nothing within ``head_room``
    of it can be another (a table top is furniture on a floor, not a floor)."""
    floors = columns.up
    if not floors.any():
        return []
    heights = columns.z[floors]
    z0 = float(heights.min())
    bins = np.floor((heights - z0) / LEVEL_BIN).astype(np.int64)
    counts = np.bincount(np.unique(bins * n_cells + columns.col[floors]) // n_cells)
    reach = int(math.ceil(step_height / LEVEL_BIN))
    running = np.concatenate([[0], np.cumsum(counts)])
    index = np.arange(len(counts))
    window = (running[np.minimum(index + reach + 1, len(counts))] - running[np.maximum(index - reach, 0)]).astype(float)
    centres = z0 + (index + 0.5) * LEVEL_BIN
    min_cells = MIN_LEVEL_AREA / resolution**2
    levels = []
    while window.max() >= min_cells:
        peak = int(np.argmax(window))
        z = round(float(np.median(heights[np.abs(bins - peak) <= reach])), 4) + 0.0  # 0.1 mm, never -0.0
        window[peak] = 0
        floor = _cell_floors(columns, n_cells, z, step_height)
        has_floor = np.isfinite(floor)
        blocked, ceiling = _column_obstacles(columns, np.where(has_floor, floor, z), np.full(n_cells, step_height),
                                             head_room=head_room)
        open_floor = has_floor & ~blocked
        if open_floor.sum() < min_cells:  # tops of things without head room over them: drop this peak only
            window[np.abs(centres - z) <= 2 * step_height] = 0
            continue
        window[np.abs(centres - z) < head_room] = 0
        area = resolution**2
        levels.append(FloorLevel(z, float(open_floor.sum() * area),
                                 float((open_floor & np.isfinite(ceiling)).sum() * area)))
    return sorted(levels, key=lambda level: level.z)


def _choose_level(levels: list[FloorLevel], floor_level: int | None) -> int:
    if floor_level is None:
        key = "roofed_area" if any(level.roofed_area > 0 for level in levels) else "area"
        return max(range(len(levels)), key=lambda i: getattr(levels[i], key))
    if isinstance(floor_level, bool) or not isinstance(floor_level, (int, np.integer)) \
            or not 0 <= floor_level < len(levels):
        found = "; ".join(f"{i}: z={level.z:.2f} m, {level.area:.1f} m^2" for i, level in enumerate(levels))
        raise ConfigError(f"floor_level={floor_level!r} is not a level of this mesh; its {len(levels)} "
                          f"level(s), lowest first: {found}")
    return int(floor_level)


def _cell_floors(columns: _Columns, n_cells: int, level_z: float, tolerance: float) -> np.ndarray:
    """Per cell the highest upward-facing surface within ``tolerance`` of ``level_z`` (NaN: none)."""
    near = columns.up & (np.abs(columns.z - level_z) <= tolerance)
    floor = np.full(n_cells, -np.inf)
    np.maximum.at(floor, columns.col[near], columns.z[near])
    return np.where(np.isfinite(floor), floor, np.nan)


def _column_obstacles(columns: _Columns, base: np.ndarray, lowest: np.ndarray, *,
                      head_room: float) -> tuple[np.ndarray, np.ndarray]:
    """Per cell: whether a surface crosses its column between ``lowest`` and ``head_room`` above
    ``base``, and the lowest surface at the head room or above (inf: open sky)."""
    rise = columns.z - base[columns.col]
    blocked = np.zeros(len(base), bool)
    blocked[columns.col[(rise > lowest[columns.col]) & (rise < head_room)]] = True
    ceiling = np.full(len(base), np.inf)
    over = rise >= head_room
    np.minimum.at(ceiling, columns.col[over], columns.z[over])
    return blocked, ceiling


def _walls_near(caster: RayCaster, grid: OccupancyGrid, xy: np.ndarray, base: np.ndarray, cells: np.ndarray,
                *, step_height: float, head_room: float) -> np.ndarray:
    """Flat cell indices that vertical surfaces occupy, seen by horizontal rays from ``cells`` at heights
    between the step and the head room: the cell holding a surface that a ray meets before the next cell's
    centre, and a cell inside a solid (a box wall that the down-casts entered through its top): half its
    rays in 8 directions meet surfaces from behind. Fewer would do in a lone box, but boxes that abut or
    overlap (walls meeting at a corner) hide some of its faces behind their own front faces."""
    if not cells.size:
        return cells
    rows, cols = grid.cells.shape
    n_heights = max(2, int(math.ceil((head_room - step_height) / RAY_SPACING)) + 1)
    margin = min(0.02, (head_room - step_height) / 4)
    heights = np.linspace(step_height + margin, head_room - margin, n_heights)
    vote_height = heights[n_heights // 2]  # solids that the column test misses span the whole band
    occupied = []
    for height in heights:
        directions = COMPASS if height == vote_height else COMPASS[::2]
        ray_dirs = np.tile(directions, (len(cells), 1))
        origins = np.repeat(np.column_stack([xy[cells], base[cells] + height]), len(directions), axis=0)
        distance, face = caster.cast(origins, ray_dirs)
        hit = face >= 0
        behind = np.zeros(len(origins), bool)
        behind[hit] = np.einsum("ij,ij->i", caster.mesh.normals[face[hit]], ray_dirs[hit]) > 0
        near = hit & (distance <= grid.resolution)
        # The cell on the solid's side of the surface: a wall face on a cell boundary occupies the wall's
        # cells, not the room's (a surface seen from behind is entered from inside its solid).
        reach = distance[near] + np.where(behind[near], -1e-4, 1e-4)
        ix, iy = grid.cell_of(origins[near, :2] + reach[:, None] * ray_dirs[near, :2])
        inside_grid = (ix >= 0) & (ix < cols) & (iy >= 0) & (iy < rows)
        occupied.append(iy[inside_grid] * cols + ix[inside_grid])
        if height == vote_height:
            occupied.append(cells[behind.reshape(len(cells), len(directions)).sum(axis=1) * 2 >= len(directions)])
    return np.unique(np.concatenate(occupied))


# ----------------------------------------------------------------------------- parts and materials


def part_at(mesh: TriangleMesh, caster: RayCaster, origins, directions) -> list[str | None]:
    """The part name of the triangle each ray hits first (None: no hit, or a mesh without part names)."""
    if caster.mesh is not mesh:
        raise ConfigError("part_at's caster was built on another mesh")
    _, face = caster.cast(origins, directions)
    part = mesh.face_part[np.maximum(face, 0)]
    return [mesh.parts[p] if f >= 0 and p < len(mesh.parts) else None for f, p in zip(face, part)]


def read_material_map(path: str | Path) -> dict[str, str]:
    """A YAML mapping of part names (fnmatch patterns, matched case-insensitively, first match wins) to
    acoustic material names of pyroomacoustics' database, e.g. ``"Wall*": brickwork``."""
    import yaml

    path = Path(path)
    if not path.is_file():
        raise ConfigError(f"material map {path} does not exist")
    try:
        document = yaml.safe_load(path.read_text())
    except (OSError, UnicodeDecodeError, yaml.YAMLError) as err:
        raise ConfigError(f"cannot read material map {path}: {err}") from err
    document = {} if document is None else document
    if not isinstance(document, dict) or not all(isinstance(k, str) and isinstance(v, str)
                                                 for k, v in document.items()):
        raise ConfigError(f"material map {path} must map part names (fnmatch patterns allowed) to acoustic "
                          "material names, one 'pattern: material' per line, e.g. '\"Wall*\": brickwork'")
    check_materials(document.values(), where=f"material map {path}")
    return document


def material_for(part: str | None, mapping: dict[str, str], default: str) -> str:
    """The acoustic material a material map gives a part: its exact name, else the first pattern that
    matches it (case-insensitively), else ``default``."""
    if part is None:
        return default
    if part in mapping:
        return mapping[part]
    name = part.lower()
    return next((material for pattern, material in mapping.items() if fnmatch.fnmatchcase(name, pattern.lower())),
                default)


def check_materials(names, *, where: str) -> None:
    """ConfigError naming every name that is not an acoustic material (with the nearest that is)."""
    unknown = sorted({str(name) for name in names if not _is_acoustic_material(name)})
    if unknown:
        raise ConfigError(f"{where} names unknown acoustic material(s): {'; '.join(map(_with_suggestion, unknown))} "
                          "(names are pyroomacoustics database entries, e.g. plasterboard, brickwork, carpet_thin)")


def _is_acoustic_material(name: str) -> bool:
    import pyroomacoustics as pra  # 1.4 s to import: only when a material map is read

    try:
        pra.Material(name)
    except (KeyError, ValueError, TypeError):
        return False
    return True


def _with_suggestion(name: str) -> str:
    from pyroomacoustics.parameters import materials_absorption_table

    close = difflib.get_close_matches(name, materials_absorption_table, n=1)
    return f"{name!r} (did you mean {close[0]!r}?)" if close else repr(name)
