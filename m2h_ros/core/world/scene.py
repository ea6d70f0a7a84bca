"""The world model, and procedural indoor scenes: connected rooms on a 1 m lattice, doors, furniture.

``Scene`` is the one geometry type that the acoustics, the camera, the navigation lattice, the episodes
and the nodes read, whatever made it: this module's generator (``source == "generated"``), a robot's
nav2 map or a scanned mesh (``source`` "map" / "mesh", built by ``plan_world``). Generated scenes
describe rooms as 1 m cells and walls as axis-aligned rectangles; an imported world describes rooms as
polygons over its floor-plan raster (``plan``, ``room_labels``), its acoustic surfaces as explicit
polygons (``surfaces``) and what the camera sees as triangles (``mesh``).

A scene is a W x H block of 1 m floor cells cut into rectangles by random guillotine cuts; two
adjacent rectangles are merged into one L/T/Z-shaped (non-convex) room in the default preset.
Rooms are joined by 1 m doors along a random spanning tree of the room adjacency graph (plus
sometimes one extra door that makes a loop). A door is a gap in the shared wall from the floor up
to ``door_height`` with a lintel wall above it. Furniture boxes sit inside single cells and are
only placed where they keep every free cell reachable.

Everything is drawn from ``numpy.random.default_rng`` seeded with the scene seed and the preset,
so the same seed and preset always give the same scene (and fingerprint).
"""

from __future__ import annotations

import functools
import hashlib
import json
from collections import deque
from dataclasses import dataclass, field
from functools import cached_property
from typing import Any

import numpy as np

from m2h_ros.core.world.navgrid import HEADING_STEPS, NavGrid
from m2h_ros.errors import ConfigError, M2HError

# Residential surfaces (pyroomacoustics database names): hard walls and ceilings, wooden, tiled or
# carpeted floors. Most of a furnished home's absorption is its furnishing (FURNISHINGS), not its
# shell. The list lengths fix how many random draws a scene takes, so keep them (8, 7, 4).
WALL_MATERIALS = ("plasterboard", "rough_lime_wash", "wooden_lining", "brickwork", "limestone_wall",
                  "brick_wall_rough", "smooth_brickwork_10mm_pointing", "ceramic_tiles")
FLOOR_MATERIALS = ("audience_floor", "stage_floor", "linoleum_on_concrete", "marble_floor",
                   "carpet_thin", "carpet_soft_10mm", "carpet_rubber_5mm")
# Repeats weight the draw: most homes have plain plasterboard ceilings.
CEILING_MATERIALS = ("ceiling_plasterboard", "ceiling_plasterboard", "ceiling_plasterboard", "wood_1.6cm")
OBSTACLE_MATERIALS = ("wood_16mm", "plywood_thin", "chairs_wooden", "chairs_medium_upholstered")
# Furnishing of a room: (pyroomacoustics material, m^2 of it per m^2 of floor). Acoustically it is
# an equivalent absorption area (see acoustics.room_absorption); it has no geometry. Upholstery
# stands for sofas, armchairs and beds, curtains for window drapes, wood for cabinets and shelves.
FURNISHINGS: dict[str, tuple[tuple[str, float], ...]] = {
    "bare": (),
    "sparse": (("wood_16mm", 0.3), ("chairs_upholstered_moderate", 0.15), ("curtains_fabric", 0.15)),
    "kitchen": (("wood_16mm", 0.5), ("chairs_upholstered_moderate", 0.15), ("curtains_fabric", 0.15)),
    "dining": (("chairs_upholstered_moderate", 0.2), ("curtains_fabric", 0.15), ("wood_16mm", 0.3)),
    "living": (("chairs_heavy_upholstered", 0.25), ("curtains_fabric_folded", 0.15), ("wood_16mm", 0.2)),
    "bedroom": (("chairs_heavy_upholstered", 0.3), ("curtains_velvet", 0.15), ("wood_16mm", 0.2)),
    "study": (("chairs_upholstered_cloth", 0.2), ("curtains_fabric", 0.15), ("wood_16mm", 0.5)),
}
# Draw weights of the furnishings for generated rooms (a few sparse, live rooms); "bare" is for hand-made scenes.
FURNISHING_WEIGHTS = {"sparse": 0.05, "kitchen": 0.15, "dining": 0.15, "living": 0.25, "bedroom": 0.25,
                      "study": 0.15}
# Material name (as pyroomacoustics.Material knows it) -> the surface it is used for.
MATERIALS: dict[str, str] = {
    **{name: "furnishing" for items in FURNISHINGS.values() for name, _ in items},  # shared: later wins
    **{name: "wall" for name in WALL_MATERIALS},
    **{name: "floor" for name in FLOOR_MATERIALS},
    **{name: "ceiling" for name in CEILING_MATERIALS},
    **{name: "obstacle" for name in OBSTACLE_MATERIALS},
}

# Distinct, saturated-enough room colours (RGB in [0, 1]); rooms draw from them without repeats.
ROOM_COLORS = ((0.80, 0.36, 0.33), (0.35, 0.62, 0.82), (0.45, 0.72, 0.40), (0.88, 0.70, 0.30),
               (0.62, 0.45, 0.78), (0.30, 0.72, 0.70), (0.85, 0.50, 0.68), (0.60, 0.55, 0.42))
OBSTACLE_COLOR = (0.42, 0.30, 0.20)

SCENE_SPLITS: dict[str, tuple[int, ...]] = {
    "train": tuple(range(0, 12)),
    # The train scenes and 12 more (the learned walkers approach the target much less in unseen
    # scenes than in these, docs/design/policies.md); its first 12 are train's, their banks shared (same fingerprints).
    # Seed 19 is left out: one of its rooms rings longer (band RT60 1.05 s) than the 1.0 s RIRs hold.
    "train24": (*range(0, 19), *range(20, 25)),
    # train24 and 24 more (pi^N + Stop still walks unseen scenes much worse, docs/design/policies.md).
    # Left out as 19 is: seeds whose rooms ring to 0.99 s or longer (Eyring, any band): 35, 40, 42, 43.
    "train48": (*range(0, 19), *range(20, 35), *range(36, 40), 41, *range(44, 53)),
    "val": tuple(range(1000, 1003)),
    "test": tuple(range(2000, 2003)),
}

_FINGERPRINT_VERSION = 2


@dataclass(frozen=True)
class Room:
    name: str
    cells: tuple[tuple[int, int], ...]   # 1x1 m floor cells (ix, iy), sorted; () in an imported world
    wall_material: str
    floor_material: str
    ceiling_material: str
    color: tuple[float, float, float]
    furnishing: str = "bare"  # a key of FURNISHINGS
    polygon: tuple[tuple[float, float], ...] = ()  # imported world: the floor's outline, metres
    floor_area: float = 0.0                        # imported world: m^2 of floor

    @property
    def area(self) -> float:
        return float(len(self.cells)) if self.cells else self.floor_area

    def outline(self) -> np.ndarray:
        """Counter-clockwise polygon corners (K, 2) of the room's floor, collinear points removed."""
        return cells_outline(self.cells) if self.cells else np.asarray(self.polygon, np.float64)


@dataclass(frozen=True)
class Wall:
    """Vertical rectangle from ``p0`` to ``p1`` in plan, z0..z1.

    Generated scenes: axis-aligned (p0 < p1 along the wall), ``rooms`` = (room on the low side, room
    on the high side) of the wall line: for a wall at x = const, (room at smaller x, room at larger x);
    for y = const, (room below, room above). Imported worlds: any direction, ``rooms`` = (the room it
    faces, the room behind it or -1 for solid).
    """
    p0: tuple[float, float]
    p1: tuple[float, float]
    z0: float
    z1: float
    material: str
    rooms: tuple[int, int]

    @property
    def is_lintel(self) -> bool:
        return self.z0 > 0.0


@dataclass(frozen=True)
class Obstacle:
    xmin: float
    ymin: float
    xmax: float
    ymax: float
    height: float
    material: str


@dataclass(frozen=True)
class Surface:
    """One planar reflecting polygon of an imported world's acoustics: the room it faces, its corners
    (K, 3) in order, the unit normal pointing away from that room, and its material."""
    room: int
    corners: tuple[tuple[float, float, float], ...]
    outward: tuple[float, float, float]
    material: str


@dataclass(frozen=True, eq=False)
class Scene:
    """One world. Compare scenes with ``fingerprint()``; equality is identity."""
    scene_id: str
    seed: int
    height: float
    rooms: tuple[Room, ...]
    walls: tuple[Wall, ...]
    obstacles: tuple[Obstacle, ...]
    grid: NavGrid
    preset: str = "default"
    door_height: float = 2.1
    size: tuple[int, int] = field(default=(0, 0))   # (W, H) cells of the bounding block
    source: str = "generated"   # "generated", "map" (a nav2 map) or "mesh" (a scanned or exported mesh)
    # Imported worlds only: the floor-plan raster (a map's own cells), each plan cell's room (-1: none),
    # the acoustic polygons, what the camera sees, and the hash of the inputs and settings.
    plan: Any = None                  # frames.OccupancyGrid
    room_labels: np.ndarray | None = None
    surfaces: tuple[Surface, ...] = ()
    mesh: Any = None                  # raycast.TriangleMesh
    import_fingerprint: str = ""

    def fingerprint(self) -> str:
        """Stable hash of the geometry and materials (not colours or ids): a cache key."""
        return self.import_fingerprint or self._fingerprint

    @property
    def imported(self) -> bool:
        return self.source != "generated"

    @property
    def world_id(self) -> str:
        """What episodes, EpisodeInfo and so bags name the scene by: its id, and for an imported world
        also its fingerprint, so a bag says which version of a map or mesh it was recorded in."""
        return f"{self.scene_id}@{self.fingerprint()}" if self.imported else self.scene_id

    @cached_property
    def _fingerprint(self) -> str:
        canonical = {
            "version": _FINGERPRINT_VERSION,
            "height": _r(self.height),
            "rooms": [[list(map(list, r.cells)), r.wall_material, r.floor_material,
                       r.ceiling_material, r.furnishing] for r in self.rooms],
            "walls": [[_r(*w.p0), _r(*w.p1), _r(w.z0), _r(w.z1), w.material, list(w.rooms)]
                      for w in self.walls],
            "obstacles": [[_r(o.xmin, o.ymin, o.xmax, o.ymax, o.height), o.material]
                          for o in self.obstacles],
        }
        text = json.dumps(canonical, sort_keys=True, separators=(",", ":"))
        return hashlib.sha256(text.encode()).hexdigest()[:16]

    @cached_property
    def cell_room(self) -> np.ndarray:
        """(W, H) int array: room index of floor cell (ix, iy), -1 outside."""
        grid = np.full(self.size, -1, dtype=np.int64)
        for index, room in enumerate(self.rooms):
            cells = np.asarray(room.cells)
            grid[cells[:, 0], cells[:, 1]] = index
        grid.setflags(write=False)
        return grid

    @property
    def bounds(self) -> tuple[float, float, float, float]:
        """(xmin, ymin, xmax, ymax) of the floor plan, metres."""
        if self.imported:
            rows, cols = self.plan.cells.shape
            corners = self.plan.cell_centres(np.array([-0.5, cols - 0.5, -0.5, cols - 0.5]),
                                             np.array([-0.5, -0.5, rows - 0.5, rows - 0.5]))
            return (*(float(v) for v in corners.min(axis=0)), *(float(v) for v in corners.max(axis=0)))
        return 0.0, 0.0, float(self.size[0]), float(self.size[1])

    @property
    def doors(self) -> tuple[Wall, ...]:
        """The lintels; each spans exactly one door gap."""
        return tuple(w for w in self.walls if w.is_lintel)

    def room_at(self, xy) -> int:
        """Room index at floor point ``xy`` (metres), -1 outside."""
        if self.imported:
            ix, iy = (int(v) for v in self.plan.cell_of(np.asarray(xy, dtype=np.float64)[:2]))
            rows, cols = self.room_labels.shape
            return int(self.room_labels[iy, ix]) if 0 <= ix < cols and 0 <= iy < rows else -1
        ix, iy = (int(np.floor(v)) for v in np.asarray(xy, dtype=np.float64)[:2])
        if 0 <= ix < self.size[0] and 0 <= iy < self.size[1]:
            return int(self.cell_room[ix, iy])
        return -1

    def outline(self) -> np.ndarray:
        """Counter-clockwise corners (K, 2) of a generated scene's whole floor plan."""
        return cells_outline([c for r in self.rooms for c in r.cells])



@dataclass(frozen=True)
class _Preset:
    sizes: tuple[tuple[int, int], ...]   # candidate (W, H) of the cell block
    n_rects: tuple[int, int]             # inclusive range of guillotine rectangles
    merge_nonconvex: bool                # merge two rectangles into one L/T/Z room
    n_obstacles: tuple[int, int]         # inclusive range
    extra_door_prob: float               # chance of one extra door (a loop between rooms)
    min_side: int = 2                    # smallest rectangle side, cells
    min_free_cells_per_room: int = 3


PRESETS: dict[str, _Preset] = {
    "default": _Preset(
        sizes=tuple((w, h) for w in range(6, 10) for h in range(5, 8) if 34 <= w * h <= 60),
        n_rects=(4, 6), merge_nonconvex=True, n_obstacles=(2, 4), extra_door_prob=0.5),
    "small": _Preset(sizes=((4, 3), (5, 3)), n_rects=(2, 2), merge_nonconvex=False,
                     n_obstacles=(1, 1), extra_door_prob=0.0),
}
_PRESET_SALT = {"default": 0, "small": 1}
_MAX_ATTEMPTS = 100
CEILING_HEIGHT = 2.7
DOOR_HEIGHT = 2.1


def generate_scene(seed: int, *, preset: str = "default", scene_id: str | None = None) -> Scene:
    """Build the scene of ``seed`` (deterministic). ``scene_id`` defaults to ``<preset>_<seed>``."""
    if preset not in PRESETS:
        raise ConfigError(f"preset={preset!r} is unknown; choose one of {sorted(PRESETS)}")
    if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or seed < 0:
        raise ConfigError(f"seed={seed!r} must be a non-negative int")
    return _generate(int(seed), preset, scene_id or f"{preset}_{int(seed):05d}")


def load_split(split: str, *, preset: str = "default") -> list[Scene]:
    """Scenes of a fixed split ("train", "train24", "train48", "val", "test"), ids ``<split>_<index:03d>``."""
    if split not in SCENE_SPLITS:
        raise ConfigError(f"split={split!r} is unknown; choose one of {sorted(SCENE_SPLITS)}")
    return [generate_scene(seed, preset=preset, scene_id=f"{split}_{i:03d}")
            for i, seed in enumerate(SCENE_SPLITS[split])]


@functools.lru_cache(maxsize=256)
def _generate(seed: int, preset_name: str, scene_id: str) -> Scene:
    preset = PRESETS[preset_name]
    rng = np.random.default_rng([seed, _PRESET_SALT[preset_name]])
    for _ in range(_MAX_ATTEMPTS):
        plan = _floor_plan(rng, preset)
        if plan is not None:
            return _build_scene(rng, preset, plan, seed=seed, preset_name=preset_name,
                                scene_id=scene_id)
    raise M2HError(f"no valid floor plan for seed {seed} preset {preset_name!r} "
                   f"after {_MAX_ATTEMPTS} attempts")


def _floor_plan(rng: np.random.Generator, preset: _Preset) -> np.ndarray | None:
    """(W, H) int array of room indices, or None when this draw does not meet the preset."""
    width, height = preset.sizes[rng.integers(len(preset.sizes))]
    n_target = int(rng.integers(preset.n_rects[0], preset.n_rects[1] + 1))
    rects = [(0, 0, width, height)]
    while len(rects) < n_target:
        splittable = [i for i, r in enumerate(rects) if _cut_axes(r, preset.min_side)]
        if not splittable:
            return None
        areas = np.array([_area(rects[i]) for i in splittable], dtype=np.float64)
        x0, y0, x1, y1 = rects.pop(splittable[rng.choice(len(splittable), p=areas / areas.sum())])
        axes = _cut_axes((x0, y0, x1, y1), preset.min_side)
        axis = axes[rng.integers(len(axes))]
        lo, hi = (x0, x1) if axis == 0 else (y0, y1)
        cut = int(rng.integers(lo + preset.min_side, hi - preset.min_side + 1))
        rects += [(x0, y0, cut, y1), (cut, y0, x1, y1)] if axis == 0 else \
                 [(x0, y0, x1, cut), (x0, cut, x1, y1)]
    labels = np.zeros((width, height), dtype=np.int64)
    for index, (x0, y0, x1, y1) in enumerate(rects):
        labels[x0:x1, y0:y1] = index
    if preset.merge_nonconvex:
        # Two adjacent rectangles whose union is not a rectangle make a non-convex room.
        pairs = sorted(p for p in _shared_edges(labels)
                       if _bbox_area(rects[p[0]], rects[p[1]]) > _area(rects[p[0]]) + _area(rects[p[1]]))
        if not pairs:
            return None
        keep, drop = pairs[rng.integers(len(pairs))]
        labels[labels == drop] = keep
        labels = np.unique(labels, return_inverse=True)[1].reshape(labels.shape)
    return labels


def _build_scene(rng: np.random.Generator, preset: _Preset, labels: np.ndarray, *, seed: int,
                 preset_name: str, scene_id: str) -> Scene:
    n_rooms = int(labels.max()) + 1
    doors = _choose_doors(rng, _shared_edges(labels), n_rooms, preset.extra_door_prob)
    wall_mats = rng.choice(len(WALL_MATERIALS), size=n_rooms, replace=False)
    floor_mats = rng.choice(len(FLOOR_MATERIALS), size=n_rooms, replace=n_rooms > len(FLOOR_MATERIALS))
    ceiling_mats = rng.integers(len(CEILING_MATERIALS), size=n_rooms)
    colors = rng.choice(len(ROOM_COLORS), size=n_rooms, replace=False)
    surfaces = [(WALL_MATERIALS[wall_mats[i]], FLOOR_MATERIALS[floor_mats[i]],
                 CEILING_MATERIALS[ceiling_mats[i]], ROOM_COLORS[colors[i]]) for i in range(n_rooms)]
    obstacles = _place_obstacles(rng, preset, labels, doors)
    # Drawn last, so the floor plan and the furniture boxes do not depend on the furnishing list.
    names = sorted(FURNISHING_WEIGHTS)
    weights = np.array([FURNISHING_WEIGHTS[n] for n in names])
    furnishings = [names[i] for i in rng.choice(len(names), size=n_rooms, p=weights / weights.sum())]
    return build_scene(labels, doors=doors, obstacles=obstacles, surfaces=surfaces, seed=seed,
                       preset=preset_name, scene_id=scene_id, furnishings=furnishings)


def build_scene(labels, *, doors=(), obstacles: tuple[Obstacle, ...] = (), surfaces=None,
                furnishings=None, scene_id: str = "custom", seed: int = 0,
                preset: str = "custom") -> Scene:
    """Assemble a scene from an explicit plan (tests, hand-made layouts).

    ``labels``: (W, H) int array, room index of each floor cell (-1 = outside). ``doors``: pairs of
    4-adjacent cells ((x, y), (x', y')) in different rooms. ``obstacles`` occupy the cell holding
    their (xmin, ymin) corner. ``surfaces``: per room (wall, floor, ceiling material, colour);
    default: the i-th entry of each material list and of ROOM_COLORS. ``furnishings``: per room a
    key of FURNISHINGS (default "bare": only the surfaces absorb).
    """
    labels = np.array(labels, dtype=np.int64)
    if labels.ndim != 2 or labels.max() < 0:
        raise ConfigError(f"labels must be a 2-D room index array with a room, got {labels.shape}")
    n_rooms = int(labels.max()) + 1
    if set(np.unique(labels[labels >= 0]).tolist()) != set(range(n_rooms)):
        raise ConfigError(f"labels must use room indices 0..{n_rooms - 1} without gaps")
    door_keys = {_edge_key(a, b) for a, b in doors}
    for a, b in door_keys:
        if abs(a[0] - b[0]) + abs(a[1] - b[1]) != 1 or min(*a, *b) < 0 \
                or max(a[0], b[0]) >= labels.shape[0] or max(a[1], b[1]) >= labels.shape[1] \
                or labels[a] == labels[b] or min(labels[a], labels[b]) < 0:
            raise ConfigError(f"door {(a, b)} must join 4-adjacent cells of two different rooms")
    if surfaces is None:
        surfaces = [(WALL_MATERIALS[i % len(WALL_MATERIALS)], FLOOR_MATERIALS[i % len(FLOOR_MATERIALS)],
                     CEILING_MATERIALS[i % len(CEILING_MATERIALS)], ROOM_COLORS[i % len(ROOM_COLORS)])
                    for i in range(n_rooms)]
    if len(surfaces) != n_rooms:
        raise ConfigError(f"surfaces has {len(surfaces)} entries for {n_rooms} rooms")
    furnishings = ["bare"] * n_rooms if furnishings is None else list(furnishings)
    if len(furnishings) != n_rooms or not set(furnishings) <= set(FURNISHINGS):
        raise ConfigError(f"furnishings must name one of {sorted(FURNISHINGS)} per room "
                          f"({n_rooms}), got {furnishings!r}")
    rooms = tuple(
        Room(name=f"room{i}", cells=tuple(sorted((int(x), int(y)) for x, y in np.argwhere(labels == i))),
             wall_material=wall, floor_material=floor, ceiling_material=ceiling,
             color=tuple(float(c) for c in color), furnishing=furnishing)
        for i, ((wall, floor, ceiling, color), furnishing) in enumerate(zip(surfaces, furnishings)))
    blocked = {(int(np.floor(o.xmin)), int(np.floor(o.ymin))) for o in obstacles}
    free = [(int(x), int(y)) for x, y in np.argwhere(labels >= 0) if (x, y) not in blocked]
    free.sort(key=lambda c: (c[1], c[0]))   # nodes in row-major order
    grid = NavGrid(np.array(free).reshape(-1, 2), [labels[c] for c in free],
                   _crossing_rule(labels, door_keys))
    if grid.n_components != 1:
        raise M2HError(f"scene {scene_id}: navigation grid has {grid.n_components} components")
    walls = _walls(labels, door_keys, rooms, CEILING_HEIGHT, DOOR_HEIGHT)
    return Scene(scene_id=scene_id, seed=seed, height=CEILING_HEIGHT, rooms=rooms, walls=walls,
                 obstacles=tuple(obstacles), grid=grid, preset=preset, door_height=DOOR_HEIGHT,
                 size=labels.shape)


def isolated_room(scene: Scene, room_index: int) -> Scene:
    """One room of ``scene`` on its own (doors shut, neighbours gone), with its surfaces,
    furnishing and furniture boxes: the closed room that Sabine's and Eyring's formulas describe."""
    if not 0 <= room_index < len(scene.rooms):
        raise ConfigError(f"room {room_index} is not a room of scene {scene.scene_id}")
    room = scene.rooms[room_index]
    labels = np.where(scene.cell_room == room_index, 0, -1)
    boxes = tuple(o for o in scene.obstacles if scene.room_at((o.xmin, o.ymin)) == room_index)
    return build_scene(labels, obstacles=boxes,
                       surfaces=[(room.wall_material, room.floor_material, room.ceiling_material, room.color)],
                       furnishings=[room.furnishing], scene_id=f"{scene.scene_id}_{room.name}",
                       seed=scene.seed, preset=scene.preset)


def _crossing_rule(labels: np.ndarray, doors: set):
    """Whether a step between two 4-adjacent cells is open: same room, or through a door."""
    def can_cross(a: tuple[int, int], b: tuple[int, int]) -> bool:
        return labels[a] == labels[b] or _edge_key(a, b) in doors
    return can_cross


def _choose_doors(rng: np.random.Generator, shared: dict, n_rooms: int,
                  extra_door_prob: float) -> set:
    """Edge keys of the door gaps: a random spanning tree over adjacent rooms, maybe one extra."""
    pairs = sorted(shared)
    parent = list(range(n_rooms))

    def root(i: int) -> int:
        while parent[i] != i:
            i = parent[i]
        return i

    tree, rest = [], []
    for index in rng.permutation(len(pairs)):
        a, b = pairs[index]
        if root(a) != root(b):
            parent[root(a)] = root(b)
            tree.append(pairs[index])
        else:
            rest.append(pairs[index])
    if rest and rng.random() < extra_door_prob:
        tree.append(rest[0])
    return {shared[p][rng.integers(len(shared[p]))] for p in tree}


def _place_obstacles(rng, preset: _Preset, labels: np.ndarray, doors: set) -> tuple[Obstacle, ...]:
    """Furniture in single cells away from doors, kept only where every free cell stays reachable."""
    door_cells = {cell for key in doors for cell in key}
    free = {(int(x), int(y)) for x, y in np.argwhere(labels >= 0)}
    candidates = sorted(free - door_cells)
    n_wanted = int(rng.integers(preset.n_obstacles[0], preset.n_obstacles[1] + 1))
    can_cross = _crossing_rule(labels, doors)
    obstacles = []
    for index in rng.permutation(len(candidates)):
        if len(obstacles) == n_wanted:
            break
        cell = candidates[index]
        room_free = sum(1 for c in free if labels[c] == labels[cell])
        if room_free <= preset.min_free_cells_per_room or not _connected(free - {cell}, can_cross):
            continue
        free.discard(cell)
        # Rounded so the stored geometry (and the fingerprint) does not hinge on float printing.
        margins = rng.uniform(0.1, 0.3, size=4).tolist()
        obstacles.append(Obstacle(
            xmin=round(cell[0] + margins[0], 3), ymin=round(cell[1] + margins[1], 3),
            xmax=round(cell[0] + 1 - margins[2], 3), ymax=round(cell[1] + 1 - margins[3], 3),
            height=round(float(rng.uniform(0.4, 1.2)), 3),
            material=OBSTACLE_MATERIALS[rng.integers(len(OBSTACLE_MATERIALS))]))
    return tuple(obstacles)


def _connected(cells: set, can_cross) -> bool:
    start = next(iter(cells))
    seen, queue = {start}, deque([start])
    while queue:
        x, y = queue.popleft()
        for dx, dy in HEADING_STEPS.tolist():
            nxt = (x + dx, y + dy)
            if nxt in cells and nxt not in seen and can_cross((x, y), nxt):
                seen.add(nxt)
                queue.append(nxt)
    return len(seen) == len(cells)


def _walls(labels: np.ndarray, doors: set, rooms: tuple[Room, ...], height: float,
           door_height: float) -> tuple[Wall, ...]:
    """Wall rectangles on every lattice edge between different rooms (or a room and outside).

    Consecutive unit edges on one line with the same room pair merge into one wall; a door edge
    becomes a lintel from ``door_height`` to the ceiling.
    """
    width, depth = labels.shape
    padded = np.full((width + 2, depth + 2), -1, dtype=np.int64)
    padded[1:-1, 1:-1] = labels
    walls = []
    for axis in (0, 1):   # axis 0: walls on lines x = c; axis 1: walls on lines y = c
        n_lines, n_along = (width, depth) if axis == 0 else (depth, width)
        for c in range(n_lines + 1):
            run = None
            for r in range(n_along + 1):
                if r < n_along:
                    low_cell, high_cell = ((c - 1, r), (c, r)) if axis == 0 else ((r, c - 1), (r, c))
                    low, high = (int(padded[x + 1, y + 1]) for x, y in (low_cell, high_cell))
                    is_door = _edge_key(low_cell, high_cell) in doors
                    kind = (low, high, is_door) if low != high else None
                else:
                    kind = None
                if run is not None and (kind != run[0] or run[0][2]):
                    walls.append(_wall(axis, c, run[1], r, run[0], rooms, height, door_height))
                    run = None
                if kind is not None and run is None:
                    run = (kind, r)
    return tuple(walls)


def _wall(axis: int, c: int, start: int, stop: int, kind, rooms, height, door_height) -> Wall:
    low, high, is_door = kind
    p0, p1 = ((c, start), (c, stop)) if axis == 0 else ((start, c), (stop, c))
    owner = min(i for i in (low, high) if i >= 0)   # interior walls take the lower room's material
    return Wall(p0=(float(p0[0]), float(p0[1])), p1=(float(p1[0]), float(p1[1])),
                z0=door_height if is_door else 0.0, z1=height,
                material=rooms[owner].wall_material, rooms=(low, high))


def _shared_edges(labels: np.ndarray) -> dict[tuple[int, int], list]:
    """(room a, room b) with a < b -> edge keys of the unit edges they share."""
    shared: dict[tuple[int, int], list] = {}
    width, depth = labels.shape
    for x in range(width):
        for y in range(depth):
            for nx, ny in ((x + 1, y), (x, y + 1)):
                if nx < width and ny < depth and labels[x, y] != labels[nx, ny] \
                        and labels[x, y] >= 0 and labels[nx, ny] >= 0:
                    pair = tuple(sorted((int(labels[x, y]), int(labels[nx, ny]))))
                    shared.setdefault(pair, []).append(_edge_key((x, y), (nx, ny)))
    return shared


def _edge_key(a: tuple[int, int], b: tuple[int, int]) -> tuple:
    a, b = (int(a[0]), int(a[1])), (int(b[0]), int(b[1]))
    return (a, b) if a < b else (b, a)


def _cut_axes(rect, min_side: int) -> list[int]:
    x0, y0, x1, y1 = rect
    return [axis for axis, side in ((0, x1 - x0), (1, y1 - y0)) if side >= 2 * min_side]


def _area(rect) -> int:
    return (rect[2] - rect[0]) * (rect[3] - rect[1])


def _bbox_area(a, b) -> int:
    return _area((min(a[0], b[0]), min(a[1], b[1]), max(a[2], b[2]), max(a[3], b[3])))


def _r(*values: float) -> float | list[float]:
    rounded = [round(float(v), 6) for v in values]
    return rounded[0] if len(rounded) == 1 else rounded


def cells_outline(cells) -> np.ndarray:
    """Counter-clockwise corners (K, 2) of a union of unit cells without holes or pinch points."""
    cell_set = {(int(x), int(y)) for x, y in cells}
    if not cell_set:
        raise M2HError("cells_outline needs at least one cell")
    nxt = {}
    for x, y in cell_set:
        # Directed boundary edges with the interior on the left.
        for (dx, dy), start, end in (((0, -1), (x, y), (x + 1, y)),
                                     ((1, 0), (x + 1, y), (x + 1, y + 1)),
                                     ((0, 1), (x + 1, y + 1), (x, y + 1)),
                                     ((-1, 0), (x, y + 1), (x, y))):
            if (x + dx, y + dy) not in cell_set:
                nxt[start] = end
    first = min(nxt, key=lambda p: (p[1], p[0]))
    ring = [first]
    while (point := nxt[ring[-1]]) != first:
        ring.append(point)
    points = np.array(ring, dtype=np.float64)
    prev, after = np.roll(points, 1, axis=0), np.roll(points, -1, axis=0)
    cross = (points - prev)[:, 0] * (after - points)[:, 1] - (points - prev)[:, 1] * (after - points)[:, 0]
    return points[cross != 0]
