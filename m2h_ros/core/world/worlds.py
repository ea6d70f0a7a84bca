"""Where worlds come from: the generated scene splits, a robot's nav2 map, or a mesh.

A world is named by a spec, and everything that takes a scene split takes a spec in its place
(episodes, the simulator, training, evaluation, the nodes' ``world`` parameter):

* ``test``, ``train``, ... : the generated scenes of that split (``scene.SCENE_SPLITS``);
* ``map:PATH``: the nav2 map whose ``map.yaml`` is PATH (as ``map_saver_cli`` writes it);
* ``mesh:PATH``: a glTF/GLB, OBJ or PLY mesh (a scanned home, a Blender or Gazebo export).

An imported world reads its settings from an optional world file beside its input, ``<stem>.world.yaml``
(``map.world.yaml`` beside ``map.yaml``), whose keys are ``WorldFile``'s fields. Worlds are built once
per process and memoised on the files' sizes and modification times.
"""

from __future__ import annotations

import dataclasses
import difflib
import functools
import hashlib
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import yaml

from m2h_ros.core.world.plan_world import PlanSettings, PlanWorldReport, RoomSpec, build_plan_world, plan_fingerprint
from m2h_ros.core.world.scene import SCENE_SPLITS, Scene, load_split
from m2h_ros.errors import ConfigError

WORLD_KINDS = ("map", "mesh")
WORLD_FILE_SUFFIX = ".world.yaml"


@dataclass(frozen=True)
class WorldFile:
    """The settings of an imported world: the plan's (``PlanSettings``) and, for a mesh, how to read it."""
    plan: PlanSettings = PlanSettings()
    units: str = "m"                  # mesh: m, cm, mm, in, ft or a scale factor to metres
    up_axis: str = ""                 # mesh: "z" or "y" ("": y for glTF, z otherwise)
    floor_level: int | None = None    # mesh: which storey, from the lowest (None: the largest)
    resolution: float = 0.05          # mesh: m per cell of the plan cast from it
    head_room: float = 1.8            # mesh: free height a floor cell needs
    materials: str = ""               # mesh: YAML of part name (patterns allowed) -> acoustic material
    path: str = ""                    # the world file read ("" = none, all defaults)


def is_world_spec(split: str) -> bool:
    """Whether ``split`` names an imported world (``map:`` or ``mesh:``) rather than a generated split."""
    return isinstance(split, str) and split.split(":", 1)[0] in WORLD_KINDS and ":" in split


def parse_world_spec(spec: str) -> tuple[str, Path]:
    """(kind, absolute path) of ``map:PATH`` / ``mesh:PATH``; the file must exist."""
    kind, _, rest = str(spec).partition(":")
    if kind not in WORLD_KINDS or not rest:
        raise ConfigError(f"world {spec!r} is not a world: use map:PATH/map.yaml, mesh:PATH (glb, gltf, obj, "
                          f"ply) or a generated split ({', '.join(sorted(SCENE_SPLITS))})")
    path = Path(rest).expanduser().resolve()
    if not path.is_file():
        raise ConfigError(f"world {spec!r}: {path} does not exist")
    return kind, path


def canonical_spec(spec: str) -> str:
    """A world spec with its path made absolute (what episodes store), or a generated split as it is."""
    if not is_world_spec(spec):
        return spec
    kind, path = parse_world_spec(spec)
    return f"{kind}:{path}"


def worlds_of(split: str, *, preset: str = "default") -> list[Scene]:
    """The scenes of a generated split, or the one world of a ``map:`` / ``mesh:`` spec."""
    if is_world_spec(split):
        return [load_world(split)]
    return load_split(split, preset=preset)


def load_world(spec: str) -> Scene:
    """The world of a ``map:`` / ``mesh:`` spec, with its world file's settings."""
    return load_world_with_report(spec)[0]


def load_world_with_report(spec: str) -> tuple[Scene, PlanWorldReport]:
    kind, path = parse_world_spec(spec)
    world_file = _world_file_path(path)
    stamp = _stamp((path, world_file))
    return _load(kind, str(path), stamp + _stamp(_named_files(kind, path, world_file, stamp)))


def _stamp(paths) -> tuple:
    return tuple((p.stat().st_size, p.stat().st_mtime_ns) if p.exists() else None for p in paths)


@functools.lru_cache(maxsize=8)
def _named_files(kind: str, path: Path, world_file: Path, stamp) -> tuple[Path, ...]:
    """The files that the input and its world file name (a map's image, a room label image, a material
    map): a change to any of them builds the world again. Read once per ``stamp`` of the two."""
    del stamp  # only part of the memo's key
    named = []
    if kind == "map":
        try:
            image = (yaml.safe_load(path.read_text()) or {}).get("image")
        except (OSError, yaml.YAMLError, AttributeError):
            image = None  # read_ros_map names what is wrong with the map file
        if isinstance(image, str) and image:
            named.append(_beside(path, image))
    settings = read_world_file(world_file, kind=kind)
    return (*named, *(_beside(world_file, name) for name in (settings.plan.room_labels, settings.materials) if name))


def world_file_path(spec: str) -> Path:
    """Where the world file of an imported world is (or would be)."""
    return _world_file_path(parse_world_spec(spec)[1])


def _world_file_path(path: Path) -> Path:
    return path.with_name(path.name[: -len(path.suffix)] + WORLD_FILE_SUFFIX if path.suffix else
                          path.name + WORLD_FILE_SUFFIX)


@functools.lru_cache(maxsize=8)
def _load(kind: str, path: str, stamp) -> tuple[Scene, PlanWorldReport]:
    del stamp  # only part of the memo's key: a changed file is read again
    path = Path(path)
    settings = read_world_file(_world_file_path(path), kind=kind)
    name = path.parent.name if path.stem in ("map", "mesh", "scene", "world") and path.parent.name else path.stem
    if kind == "map":
        return _map_world(path, settings, name)
    return _mesh_world(path, settings, name)


def _map_world(path: Path, settings: WorldFile, name: str) -> tuple[Scene, PlanWorldReport]:
    from m2h_ros.core.world.ros_map import read_ros_map

    ros_map = read_ros_map(path)
    labels, labels_sha = _user_labels(settings, ros_map.grid, ros_map.trinary.shape)
    fingerprint = plan_fingerprint(ros_map.sha256 + labels_sha, settings.plan)
    return build_plan_world(ros_map.grid, free=ros_map.free(), occupied=ros_map.occupied(), settings=settings.plan,
                            scene_id=name, source="map", fingerprint=fingerprint, what=f"map {path}",
                            user_labels=labels)


def _mesh_world(path: Path, settings: WorldFile, name: str) -> tuple[Scene, PlanWorldReport]:
    from m2h_ros.core.world.mesh_import import (material_for, mesh_floor_plan, part_at, read_material_map,
                                                read_mesh)
    from m2h_ros.core.world.raycast import RayCaster, TriangleMesh

    raw = read_mesh(path, units=settings.units, up_axis=settings.up_axis or None)
    mesh_plan = mesh_floor_plan(raw, resolution=settings.resolution, head_room=settings.head_room,
                                floor_level=settings.floor_level)
    # The chosen floor becomes z = 0: ears, sources and the camera stand on it as in every world.
    mesh = TriangleMesh(raw.vertices - [0.0, 0.0, mesh_plan.floor_z], raw.faces, raw.face_colors,
                        raw.face_part, raw.parts)
    plan_settings = settings.plan
    if mesh_plan.ceiling_z is not None:
        plan_settings = dataclasses.replace(plan_settings, wall_height=round(mesh_plan.ceiling_z - mesh_plan.floor_z, 3))
    mapping = read_material_map(_beside(path, settings.materials)) if settings.materials else {}
    caster = RayCaster(mesh)

    def surface_material(room: int, kind: str, centre: np.ndarray, outward) -> str | None:
        if not mapping:
            return None
        outward = np.asarray(outward, float)
        origin = centre - 0.3 * outward if kind == "wall" else np.array([centre[0], centre[1], 1.0])
        part = part_at(mesh, caster, origin[None], outward[None])[0]
        return material_for(part, mapping, "") or None

    grid = mesh_plan.grid
    labels, labels_sha = _user_labels(settings, grid, grid.cells.shape)
    mesh_sha = hashlib.sha256(path.read_bytes()).hexdigest()
    materials_sha = hashlib.sha256(_beside(path, settings.materials).read_bytes()).hexdigest() \
        if settings.materials else ""
    fingerprint = plan_fingerprint(mesh_sha + labels_sha + materials_sha, plan_settings,
                                   {k: getattr(settings, k) for k in ("units", "up_axis", "floor_level",
                                                                      "resolution", "head_room")})
    return build_plan_world(grid, free=grid.cells == 0, occupied=grid.cells == 100, settings=plan_settings,
                            scene_id=name, source="mesh", fingerprint=fingerprint, what=f"mesh {path}",
                            user_labels=labels, mesh=mesh, surface_material=surface_material)


def _beside(path: Path, name: str) -> Path:
    other = Path(name).expanduser()
    return other if other.is_absolute() else path.parent / other


def _user_labels(settings: WorldFile, grid, shape) -> tuple[np.ndarray | None, str]:
    """The user's rooms as (rows, cols) labels (1..R, 0 none) and a hash of what gave them."""
    plan = settings.plan
    if plan.room_labels:
        from PIL import Image

        source = _beside(Path(settings.path), plan.room_labels)
        try:
            image = np.asarray(Image.open(source))
        except (OSError, ValueError) as err:
            raise ConfigError(f"room label image {source} cannot be read ({err})") from err
        if image.ndim != 2 or image.shape != tuple(shape):
            raise ConfigError(f"room label image {source} must be one channel of {shape[1]} x {shape[0]} pixels "
                              f"(the map's size), got {image.shape}")
        return np.flipud(image).astype(np.int64), hashlib.sha256(source.read_bytes()).hexdigest()
    polygons = [room.polygon for room in plan.rooms if room.polygon]
    if not polygons:
        return None, ""
    if len(polygons) != len(plan.rooms):
        raise ConfigError(f"world file {settings.path}: give every room a polygon, or none (automatic rooms)")
    from skimage.draw import polygon as fill

    labels = np.zeros(shape, np.int64)
    for index, corners in enumerate(polygons, start=1):
        corners = np.asarray(corners, float)
        ix, iy = _grid_coordinates(grid, corners)
        rows, cols = fill(iy, ix, shape=shape)
        labels[rows, cols] = index
    return labels, ""


def _grid_coordinates(grid, xy: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Continuous cell coordinates (x along columns, y along rows, cell centres at integers)."""
    dx, dy = xy[:, 0] - grid.origin[0], xy[:, 1] - grid.origin[1]
    c, s = np.cos(grid.yaw), np.sin(grid.yaw)
    return (c * dx + s * dy) / grid.resolution - 0.5, (-s * dx + c * dy) / grid.resolution - 0.5


# ----------------------------------------------------------------------------- world file

_PLAN_KEYS = tuple(f.name for f in dataclasses.fields(PlanSettings))
_MESH_KEYS = ("units", "up_axis", "floor_level", "resolution", "head_room", "materials")
_ROOM_KEYS = tuple(f.name for f in dataclasses.fields(RoomSpec))


def read_world_file(path: Path, *, kind: str) -> WorldFile:
    """The settings in a world file (all defaults where there is none); unknown keys are errors."""
    if not path.exists():
        return WorldFile()
    try:
        document = yaml.safe_load(path.read_text()) or {}
    except (OSError, yaml.YAMLError) as err:
        raise ConfigError(f"world file {path} cannot be read: {err}") from err
    if not isinstance(document, dict):
        raise ConfigError(f"world file {path} must be a mapping of settings, got {type(document).__name__}")
    known = _PLAN_KEYS + (_MESH_KEYS if kind == "mesh" else ())
    for key in document:
        if key not in known:
            raise ConfigError(f"world file {path}: unknown setting {key!r}{_nearest(key, known)}; "
                              f"known: {', '.join(known)}")
    plan = {k: v for k, v in document.items() if k in _PLAN_KEYS}
    rooms = plan.pop("rooms", ()) or ()
    if rooms == "auto":
        rooms = ()
    if not isinstance(rooms, list | tuple):
        raise ConfigError(f"world file {path}: rooms must be 'auto' or a list of rooms")
    specs = []
    for number, room in enumerate(rooms):
        if not isinstance(room, dict):
            raise ConfigError(f"world file {path}: room {number} must be a mapping")
        for key in room:
            if key not in _ROOM_KEYS:
                raise ConfigError(f"world file {path}: room {number} has unknown setting {key!r}"
                                  f"{_nearest(key, _ROOM_KEYS)}")
        polygon = tuple(tuple(float(v) for v in corner) for corner in room.get("polygon", ()))
        if polygon and (len(polygon) < 3 or any(len(c) != 2 for c in polygon)):
            raise ConfigError(f"world file {path}: room {number}'s polygon needs at least 3 [x, y] corners")
        specs.append(RoomSpec(**{**room, "polygon": polygon}))
    # The acoustics look materials up only when they run: name a misspelt one now, with this file.
    from m2h_ros.core.world.mesh_import import check_materials

    named = [value for key, value in plan.items() if key.endswith("_material")]
    named += [value for spec in specs for value in (spec.wall_material, spec.floor_material, spec.ceiling_material)
              if value]
    check_materials(named, where=f"world file {path}")
    try:
        plan_settings = PlanSettings(**plan, rooms=tuple(specs))
        mesh = {k: v for k, v in document.items() if k in _MESH_KEYS}
        return WorldFile(plan=plan_settings, path=str(path), **mesh)
    except (TypeError, ConfigError) as err:
        raise ConfigError(f"world file {path}: {err}") from err


def _nearest(key: str, known) -> str:
    close = difflib.get_close_matches(str(key), known, n=1)
    return f" (did you mean {close[0]!r}?)" if close else ""
