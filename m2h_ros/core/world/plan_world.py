"""A world from a floor-plan raster: a robot's nav2 map, or the plan a scanned mesh casts.

From a raster of free, occupied and unknown cells (``frames.OccupancyGrid``) this builds a ``Scene``:

* floor: the free cells plus small isolated occupied blobs thicker than a wall, which are furniture
  (boxes of ``furniture_height`` that block the robot and the camera and add absorption); everything
  else (walls, unknown space) is solid; specks of noise too small to be anything are ignored;
* rooms: cut at doorways (the floor's narrow necks, a watershed of its clearance grown from seeds
  farther than half ``door_width`` from any wall) or given by the user as labels; rooms smaller than
  ``min_room_area`` join their neighbour;
* walls: each room's boundary, traced on the raster and split into the part that borders solid space
  (walls, simplified to ``wall_tolerance`` so the image-source model stays tractable) and the part that
  borders another room (an opening; a lintel above it where it is no wider than ``door_width``); the
  floor and ceiling polygons share those very corners, so the room is closed for the ray tracer;
* the navigation lattice: nodes every ``lattice_spacing`` where a robot of ``robot_radius`` fits, an
  edge where it can drive straight from one node to the next; one connected component is kept;
* the camera's triangles: the same surfaces, coloured as the generated scenes are (room colour, a
  checkered floor as the motion cue the policies learnt on).
"""

from __future__ import annotations

import hashlib
import json
from dataclasses import asdict, dataclass, field

import numpy as np
from scipy import ndimage
from scipy.sparse import csr_matrix
from scipy.sparse.csgraph import connected_components

from m2h_ros.core.world.frames import OccupancyGrid
from m2h_ros.core.world.navgrid import HEADING_STEPS, NavGrid
from m2h_ros.core.world.raycast import TriangleMesh
from m2h_ros.core.world.scene import FURNISHINGS, OBSTACLE_COLOR, ROOM_COLORS, Obstacle, Room, Scene, Surface, Wall
from m2h_ros.errors import ConfigError

#: Bump whenever a change here changes the world built from the same inputs (it keys every cache).
PLAN_WORLD_VERSION = 1
WALL_THICKNESS = 0.25  # m: an isolated occupied blob no thicker than this is a piece of wall, not furniture
LATTICE_PHASES = (0.0, 0.25, 0.5, 0.75)  # offsets tried per axis, in units of the spacing
DOOR_SLACK = 0.1  # m: a traced doorway may measure this much wider than the door
DETOUR = 1.5  # a lattice edge may bend round a door jamb by at most this factor of its length
_SPECK_AREA = 0.03  # m^2: occupied or unknown specks smaller than this are sensor noise in free space


@dataclass(frozen=True)
class RoomSpec:
    """A room's name and surfaces; ``polygon`` (map metres) places it, else it names an automatic room."""
    name: str = ""
    polygon: tuple[tuple[float, float], ...] = ()
    wall_material: str = ""
    floor_material: str = ""
    ceiling_material: str = ""
    furnishing: str = ""


@dataclass(frozen=True)
class PlanSettings:
    """Everything that shapes a world built from a plan (all of it keys the world's fingerprint)."""
    wall_height: float = 2.5        # m: ceiling height (a nav2 map has none)
    door_height: float = 2.1        # m: underside of a lintel
    door_width: float = 1.0         # m: openings up to this wide are doors (rooms part there; lintel)
    lattice_spacing: float = 1.0    # m: 1 as Move2Hear's Matterport grid, 0.5 as Replica's
    robot_radius: float = 0.2       # m: a node needs this clearance, an edge all along
    furniture_max_area: float = 1.5  # m^2: isolated occupied blobs up to this are furniture
    furniture_height: float = 0.75  # m
    wall_tolerance: float = 0.1     # m: walls simplified to within this of the traced boundary (a SLAM map's ragged walls)
    min_room_area: float = 2.0      # m^2: smaller automatic rooms join a neighbour
    lattice_yaw: float | None = None  # degrees: the lattice's turn in the input's frame; None: along the walls
    wall_material: str = "plasterboard"
    floor_material: str = "linoleum_on_concrete"
    ceiling_material: str = "ceiling_plasterboard"
    furnishing: str = "living"
    furniture_material: str = "wood_16mm"
    rooms: tuple[RoomSpec, ...] = ()  # polygons: the user's rooms; names only: settings per automatic room
    room_labels: str = ""            # a label image (same size as the map): 0 = no room, k = room k

    def __post_init__(self) -> None:
        for name in ("wall_height", "door_height", "door_width", "lattice_spacing", "furniture_max_area",
                     "furniture_height", "wall_tolerance", "min_room_area"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, (int, float)) or not value > 0:
                raise ConfigError(f"world setting {name} must be a positive number, got {value!r}")
        if isinstance(self.robot_radius, bool) or not 0 <= self.robot_radius < 2:
            raise ConfigError(f"world setting robot_radius must be in [0, 2) m, got {self.robot_radius!r}")
        if not self.door_height < self.wall_height:
            raise ConfigError(f"world setting door_height ({self.door_height} m) must be below wall_height "
                              f"({self.wall_height} m)")
        if not 0.1 <= self.lattice_spacing <= 5:
            raise ConfigError(f"world setting lattice_spacing must be in [0.1, 5] m, got {self.lattice_spacing}")
        for room in (self, *self.rooms):
            if room.furnishing and room.furnishing not in FURNISHINGS:
                raise ConfigError(f"furnishing {room.furnishing!r} is unknown; choose one of {sorted(FURNISHINGS)}")


@dataclass(frozen=True)
class PlanWorldReport:
    """What the builder decided that a user should know (``describe()`` prints it)."""
    n_nodes: int
    dropped_components: tuple[int, ...]  # node counts of the lattice components left out
    n_furniture: int
    n_walls: int
    rooms: tuple[tuple[str, float], ...] = field(default=())  # (name, m^2)
    turn_deg: float = 0.0  # the world's frame turned from the input's by this (the lattice along the walls)

    def describe(self) -> str:
        rooms = ", ".join(f"{name} {area:.1f} m^2" for name, area in self.rooms)
        text = (f"{len(self.rooms)} rooms ({rooms}); {self.n_walls} wall faces; {self.n_furniture} furniture "
                f"blobs; lattice {self.n_nodes} nodes")
        if self.turn_deg:
            text += f" along the walls (the world's frame is the input's turned {-self.turn_deg:.1f} deg)"
        if self.dropped_components:
            text += (f"; left out {len(self.dropped_components)} unconnected lattice part(s) of "
                     f"{', '.join(map(str, self.dropped_components))} node(s)")
        return text


def plan_fingerprint(inputs_sha256: str, settings: PlanSettings, extra: dict | None = None) -> str:
    """The cache key of a world: its input files' hash, the settings and this builder's version."""
    payload = json.dumps({"inputs": inputs_sha256, "settings": asdict(settings), "extra": extra or {},
                          "version": PLAN_WORLD_VERSION}, sort_keys=True, default=str)
    return hashlib.sha256(payload.encode()).hexdigest()[:16]


def build_plan_world(plan: OccupancyGrid, *, free: np.ndarray, occupied: np.ndarray, settings: PlanSettings,
                     scene_id: str, source: str, fingerprint: str, what: str,
                     user_labels: np.ndarray | None = None, mesh: TriangleMesh | None = None,
                     surface_material=None) -> tuple[Scene, PlanWorldReport]:
    """The world of a plan raster. ``free`` / ``occupied``: (rows, cols) masks over ``plan.cells``
    (neither: unknown). ``what`` names the input in errors. ``user_labels``: (rows, cols) int room
    labels (0: none) instead of the automatic rooms. ``mesh``: what the camera sees (default: the
    built surfaces). ``surface_material(room, kind, centre, outward) -> str | None``: a material for a
    surface from elsewhere (a mesh's parts), None for the room's own.

    The world's frame is the input's turned so that the lattice runs along the building's walls
    (``lattice_yaw``; a plan whose walls lie along its axes is not turned): the moves of the lattice
    then follow corridors and pass doors however the map or mesh lies in its own frame."""
    res = float(plan.resolution)
    free, occupied = np.asarray(free, bool), np.asarray(occupied, bool)
    if free.shape != plan.cells.shape or occupied.shape != plan.cells.shape:
        raise ConfigError(f"{what}: free/occupied masks must have the plan's shape {plan.cells.shape}")
    turn = np.radians(settings.lattice_yaw) if settings.lattice_yaw is not None else wall_direction(plan, free)
    if turn:
        plan, mesh, surface_material = _turned(plan, mesh, surface_material, -turn)
    unknown = ~free & ~occupied
    speck = max(1, int(round(_SPECK_AREA / res ** 2)))
    # Specks of unknown (unseen cells in a SLAM map) are noise: free where they lie in free space, part of
    # the wall where they touch one. Then specks of occupied inside free space are noise too, and larger
    # occupied islands are furniture.
    unknown_parts, n_unk = ndimage.label(unknown)
    unknown_sizes = np.bincount(unknown_parts.ravel(), minlength=n_unk + 1)
    unknown_noise = unknown_sizes < speck
    unknown_noise[0] = False
    specks = unknown_noise[unknown_parts]
    occupied = occupied | (specks & ndimage.binary_dilation(occupied, np.ones((3, 3))))
    free = free | (specks & ~occupied)
    unknown = ~free & ~occupied
    occupied_parts, n_occ = ndimage.label(occupied, structure=np.ones((3, 3)))
    sizes = np.bincount(occupied_parts.ravel(), minlength=n_occ + 1)
    touches_unknown = np.zeros(n_occ + 1, bool)
    touches_unknown[np.unique(occupied_parts[ndimage.binary_dilation(unknown, np.ones((3, 3)))])] = True
    island = ~touches_unknown & (sizes * res ** 2 <= settings.furniture_max_area)
    island[0] = False
    noise = island & (sizes < speck)
    # A free-standing piece of wall (between two doors) is thin; furniture is not.
    half_width = ndimage.maximum(ndimage.distance_transform_edt(occupied), occupied_parts,
                                 index=np.arange(n_occ + 1)) * res
    furniture_ids = np.flatnonzero(island & ~noise & (2 * np.asarray(half_width) > WALL_THICKNESS))
    free = free | noise[occupied_parts]
    furniture = np.isin(occupied_parts, furniture_ids)
    floor = free | furniture
    if not free.any():
        raise ConfigError(f"{what} has no free space: nothing for the robot to stand on (check negate, "
                          f"free_thresh and mode)")
    if floor[0].any() or floor[-1].any() or floor[:, 0].any() or floor[:, -1].any():
        raise ConfigError(f"{what}: free space runs off the edge of the map, so the building is not closed; "
                          f"the map must be surrounded by walls or unknown space (a map saved by nav2 before "
                          f"1.3.7 says free_thresh: 0.25, which reads its unknown grey 205 as free: set 0.196)")
    labels = _rooms(floor, res, settings, user_labels, what)
    n_rooms = int(labels.max())
    specs = _room_specs(settings, n_rooms, labels, plan)
    rooms, surfaces, walls, shapes = [], [], [], []
    for index in range(n_rooms):
        mask = labels == index + 1
        rings = _room_rings(mask, labels, index + 1, plan, settings)
        exterior = max((ring for ring in rings if ring.encloses_room), key=lambda ring: abs(_signed_area(ring.points)))
        spec = specs[index]
        rooms.append(Room(name=spec.name, cells=(), wall_material=spec.wall_material,
                          floor_material=spec.floor_material, ceiling_material=spec.ceiling_material,
                          color=ROOM_COLORS[index % len(ROOM_COLORS)], furnishing=spec.furnishing,
                          polygon=tuple(map(tuple, np.round(exterior.points, 4).tolist())),
                          floor_area=float(mask.sum() * res ** 2)))
        shapes.append(rings)
    for index, rings in enumerate(shapes):
        room_surfaces, room_walls = _room_surfaces(index, rooms[index], rings, settings, surface_material)
        surfaces += room_surfaces
        walls += room_walls
    obstacles, prisms = _furniture(furniture, plan, labels, settings)
    grid, dropped = _lattice(free, labels, plan, settings, what)
    if mesh is None:
        mesh = _surfaces_mesh(rooms, surfaces, prisms, settings)
    room_labels = labels - 1
    room_labels.setflags(write=False)
    # The key of every cache built on the world: the inputs and settings, and the geometry itself, so a
    # change of this builder can never pair a world with another's banks or episodes.
    geometry = json.dumps({"inputs": fingerprint, "nodes": np.round(grid.positions, 6).tolist(),
                           "moves": grid.forward.tolist(), "height": settings.wall_height,
                           "surfaces": [[s.room, s.corners, s.material] for s in surfaces],
                           "rooms": [[r.furnishing, round(r.area, 6)] for r in rooms],
                           "obstacles": [[o.xmin, o.ymin, o.xmax, o.ymax, o.height, o.material] for o in obstacles]},
                          separators=(",", ":"))
    scene = Scene(scene_id=scene_id, seed=0, height=float(settings.wall_height), rooms=tuple(rooms),
                  walls=tuple(walls), obstacles=tuple(obstacles), grid=grid, preset=source,
                  door_height=float(settings.door_height), size=(plan.cells.shape[1], plan.cells.shape[0]),
                  source=source, plan=plan, room_labels=room_labels, surfaces=tuple(surfaces), mesh=mesh,
                  import_fingerprint=hashlib.sha256(geometry.encode()).hexdigest()[:16])
    report = PlanWorldReport(n_nodes=grid.n_nodes, dropped_components=dropped, n_furniture=len(obstacles),
                             n_walls=sum(1 for s in surfaces if s.outward[2] == 0),
                             rooms=tuple((r.name, r.area) for r in rooms), turn_deg=float(np.degrees(turn)))
    return scene, report


def wall_direction(plan: OccupancyGrid, free: np.ndarray) -> float:
    """The direction (radians in the input's frame, in [-45, 45) degrees) the building's walls run in,
    up to quarter turns: the mean over the free space's outline, traced and straightened, each piece
    weighted by its length squared (long walls decide); 0 within a degree of the input's axes."""
    from shapely.geometry import LineString
    from skimage.measure import find_contours

    angles, lengths = [], []
    for contour in find_contours(np.pad(free, 1).astype(np.float32), 0.5):
        if len(contour) < 8:
            continue
        line = np.asarray(LineString(contour[:, ::-1]).simplify(1.5).coords)
        step = np.diff(line, axis=0)
        angles.append(np.arctan2(step[:, 1], step[:, 0]))
        lengths.append(np.hypot(step[:, 0], step[:, 1]))
    if not angles:
        return 0.0
    quarter = np.angle(np.sum(np.concatenate(lengths) ** 2 * np.exp(4j * np.concatenate(angles)))) / 4
    turn = float((quarter + plan.yaw + np.pi / 4) % (np.pi / 2) - np.pi / 4)
    return 0.0 if abs(np.degrees(turn)) < 1.0 else turn


def _turned(plan: OccupancyGrid, mesh: TriangleMesh | None, surface_material, angle: float):
    """The plan and the mesh in a frame turned by ``angle`` (radians), and the material lookup taking that
    frame's points and directions (it works in the input's)."""
    c, s = np.cos(angle), np.sin(angle)
    turn = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
    origin = turn[:2, :2] @ np.asarray(plan.origin, float)
    plan = OccupancyGrid(plan.cells, plan.resolution, (float(origin[0]), float(origin[1])), plan.yaw + angle)
    if mesh is not None:
        mesh = TriangleMesh(mesh.vertices @ turn.T, mesh.faces, mesh.face_colors, mesh.face_part, mesh.parts)
    if surface_material is not None:
        lookup = surface_material

        def surface_material(room, kind, centre, outward):
            return lookup(room, kind, turn.T @ np.asarray(centre, float), tuple(turn.T @ np.asarray(outward, float)))
    return plan, mesh, surface_material


# ----------------------------------------------------------------------------- rooms


def _rooms(floor: np.ndarray, res: float, settings: PlanSettings, user_labels: np.ndarray | None,
           what: str) -> np.ndarray:
    """(rows, cols) int labels 1..R over the floor (0 elsewhere)."""
    from skimage.segmentation import watershed

    clearance = ndimage.distance_transform_edt(floor) * res
    if user_labels is not None:
        markers = np.where(floor, np.asarray(user_labels, np.int64), 0)
        if not markers.any():
            raise ConfigError(f"{what}: the given rooms cover none of the free space")
    else:
        # Seeds: floor farther than half a door's width from any wall; a door's neck has none.
        markers, _ = ndimage.label(floor & (clearance > settings.door_width / 2))
        if not markers.any():  # a floor narrower than a door everywhere: one room
            markers = floor.astype(np.int64)
    labels = watershed(-clearance, markers, mask=floor)
    # Floor the watershed could not reach from any marker (an unconnected pocket) joins no room.
    labels = _merge_small_rooms(labels, res, settings.min_room_area if user_labels is None else 0.0)
    _, labels = np.unique(labels, return_inverse=True)  # 0 stays 0 (no floor), rooms 1..R without gaps
    return labels.reshape(floor.shape)


def _merge_small_rooms(labels: np.ndarray, res: float, min_area: float) -> np.ndarray:
    """Rooms under ``min_area`` m^2 join the neighbour they share most boundary with, smallest first."""
    labels = labels.copy()
    while True:
        ids, counts = np.unique(labels[labels > 0], return_counts=True)
        small = [(c, i) for i, c in zip(ids, counts) if c * res ** 2 < min_area]
        if not small or len(ids) == 1:
            return labels
        _, room = min(small)
        ring = ndimage.binary_dilation(labels == room) & (labels > 0) & (labels != room)
        neighbours, shared = np.unique(labels[ring], return_counts=True)
        if len(neighbours) == 0:
            return labels  # an island room: nothing to join
        labels[labels == room] = neighbours[np.argmax(shared)]


def _room_specs(settings: PlanSettings, n_rooms: int, labels: np.ndarray, plan: OccupancyGrid) -> list[RoomSpec]:
    """Each room's name and surfaces: the user's (by polygon or in order) over the world's defaults."""
    given = list(settings.rooms)
    specs = []
    for index in range(n_rooms):
        spec = given[index] if index < len(given) else RoomSpec()
        specs.append(RoomSpec(
            name=spec.name or f"room{index}", polygon=spec.polygon,
            wall_material=spec.wall_material or settings.wall_material,
            floor_material=spec.floor_material or settings.floor_material,
            ceiling_material=spec.ceiling_material or settings.ceiling_material,
            furnishing=spec.furnishing or settings.furnishing))
    return specs


# ----------------------------------------------------------------------------- boundaries


@dataclass
class _Ring:
    """One closed boundary of a room: corners (K, 2) in map metres, per edge k (corner k to k + 1)
    what lies beyond it (-1 solid, else the index of the room on the other side), and whether the room
    is on the edges' left (the ring goes round it counter-clockwise, or round a hole clockwise)."""
    points: np.ndarray
    beyond: np.ndarray
    room_on_left: bool

    @property
    def encloses_room(self) -> bool:
        """An outline of the room (not of a hole in it): the room is inside the ring."""
        return self.room_on_left == (_signed_area(self.points) > 0)


def _room_rings(mask: np.ndarray, labels: np.ndarray, label: int, plan: OccupancyGrid,
                settings: PlanSettings) -> list[_Ring]:
    """The room's traced boundaries (outlines and holes), each split into runs by what lies beyond and
    each run simplified on its own (so run ends, the corners where a wall meets an opening, stay)."""
    from skimage.measure import find_contours

    padded = np.pad(mask, 1).astype(np.float32)
    padded_labels = np.pad(labels, 1)
    # At least 1.5 cells: a coarser raster's one-cell steps are not walls (a ragged map would give hundreds).
    tolerance = max(settings.wall_tolerance / plan.resolution, 1.5)
    rings = []
    for contour in find_contours(padded, 0.5):
        if len(contour) < 4:
            continue
        contour = contour[:-1] if np.allclose(contour[0], contour[-1]) else contour
        nxt = np.roll(contour, -1, axis=0)
        middle = (contour + nxt) / 2
        along = nxt - contour
        normal = np.stack([along[:, 1], -along[:, 0]], axis=1)
        normal /= np.maximum(np.linalg.norm(normal, axis=1, keepdims=True), 1e-12)
        side_a = _pixel_label(padded_labels, middle + 0.7 * normal)
        side_b = _pixel_label(padded_labels, middle - 0.7 * normal)
        other = np.where(side_a == label, side_b, side_a)
        beyond = np.where(other > 0, other - 1, -1)
        # In the grid frame's (x, y) = (col, row) the normal above is (-d row, d col): the edge's left.
        room_on_left = bool(np.mean(side_a == label) > 0.5)
        points, kinds = _simplified_runs(contour, beyond, tolerance)
        if len(points) < 3:
            continue
        # (row, col) of the padded raster -> grid cell coordinates -> map metres.
        xy = plan.cell_centres(points[:, 1] - 1.0, points[:, 0] - 1.0)
        rings.append(_Ring(xy, kinds, room_on_left))
    if not any(ring.encloses_room for ring in rings):
        raise ConfigError(f"room {label - 1} has no traceable outline")
    return rings


def _pixel_label(labels: np.ndarray, points: np.ndarray) -> np.ndarray:
    rows = np.clip(np.round(points[:, 0]).astype(np.int64), 0, labels.shape[0] - 1)
    cols = np.clip(np.round(points[:, 1]).astype(np.int64), 0, labels.shape[1] - 1)
    return labels[rows, cols]


def _simplified_runs(points: np.ndarray, beyond: np.ndarray, tolerance: float) -> tuple[np.ndarray, np.ndarray]:
    """Corners (K, 2) and per-edge kinds (K,) of a closed contour after simplifying each run of edges
    of one kind (Douglas-Peucker, ends kept)."""
    from shapely.geometry import LineString

    n = len(points)
    changes = np.flatnonzero(beyond != np.roll(beyond, 1))
    if len(changes) == 0:  # one kind all round: simplify the closed ring from its lowest-left corner
        start = int(np.lexsort((points[:, 1], points[:, 0]))[0])
        ring = np.vstack([np.roll(points, -start, axis=0), points[start:start + 1]])
        simple = np.asarray(LineString(ring).simplify(tolerance, preserve_topology=True).coords)[:-1]
        return simple, np.full(len(simple), beyond[0])
    corners, kinds = [], []
    for k, start in enumerate(changes):
        stop = changes[(k + 1) % len(changes)]
        idx = np.arange(start, start + ((stop - start) % n or n) + 1) % n
        run = points[idx]
        simple = np.asarray(LineString(run).simplify(tolerance, preserve_topology=False).coords) \
            if len(run) > 2 else run
        corners.append(simple[:-1])
        kinds.append(np.full(len(simple) - 1, beyond[start]))
    return np.vstack(corners), np.concatenate(kinds)


def _signed_area(points: np.ndarray) -> float:
    x, y = points[:, 0], points[:, 1]
    return 0.5 * float(np.dot(x, np.roll(y, -1)) - np.dot(np.roll(x, -1), y))


def _opening_widths(ring: _Ring) -> np.ndarray:
    """(K,) per edge, the straight distance across the run of edges of one kind it belongs to: for an
    opening into another room, its width (the traced line between two rooms need not be straight)."""
    n = len(ring.beyond)
    starts = np.flatnonzero(ring.beyond != np.roll(ring.beyond, 1))
    if len(starts) == 0:
        return np.full(n, np.inf)
    widths = np.empty(n)
    for k, start in enumerate(starts):
        stop = starts[(k + 1) % len(starts)]
        count = (stop - start) % n or n
        widths[(start + np.arange(count)) % n] = np.hypot(*(ring.points[stop % n] - ring.points[start]))
    return widths


def _room_surfaces(index: int, room: Room, rings: list[_Ring], settings: PlanSettings,
                   surface_material) -> tuple[list[Surface], list[Wall]]:
    """A room's acoustic polygons (walls and lintels facing it, its floors and ceilings) and its walls."""
    height, door = settings.wall_height, settings.door_height

    def material(kind: str, corners, outward, own: str) -> str:
        found = surface_material(index, kind, np.mean(corners, axis=0), outward) if surface_material else None
        return found or own

    surfaces, walls = [], []
    for ring in rings:
        widths = _opening_widths(ring)
        for k in range(len(ring.points)):
            p0, p1 = ring.points[k], ring.points[(k + 1) % len(ring.points)]
            length = float(np.hypot(*(p1 - p0)))
            beyond = int(ring.beyond[k])
            if length < 1e-6 or (beyond >= 0 and widths[k] > settings.door_width + DOOR_SLACK):
                continue  # nothing there: a degenerate edge or an open-plan boundary
            z0 = 0.0 if beyond < 0 else door  # a doorway has its lintel above it, on this room's side
            left = np.array([-(p1 - p0)[1], (p1 - p0)[0]]) / length
            away = -left if ring.room_on_left else left
            outward = (float(away[0]), float(away[1]), 0.0)
            corners = tuple(tuple(round(float(v), 6) for v in c)
                            for c in ((*p0, z0), (*p1, z0), (*p1, height), (*p0, height)))
            surfaces.append(Surface(index, corners, outward,
                                    material("wall", np.asarray(corners), outward, room.wall_material)))
            if beyond < 0 or index < beyond:  # a lintel is one wall, listed by its lower room
                walls.append(Wall(p0=(float(p0[0]), float(p0[1])), p1=(float(p1[0]), float(p1[1])),
                                  z0=z0, z1=height, material=room.wall_material, rooms=(index, beyond)))
    for ring in rings:
        if not ring.encloses_room:
            continue
        outline = ring.points if _signed_area(ring.points) > 0 else ring.points[::-1]
        for z, outward, kind, own in ((0.0, (0.0, 0.0, -1.0), "floor", room.floor_material),
                                      (height, (0.0, 0.0, 1.0), "ceiling", room.ceiling_material)):
            corners = tuple((round(float(x), 6), round(float(y), 6), z) for x, y in outline)
            surfaces.append(Surface(index, corners, outward, material(kind, np.asarray(corners), outward, own)))
    return surfaces, walls


# ----------------------------------------------------------------------------- furniture and lattice


def _furniture(furniture: np.ndarray, plan: OccupancyGrid, labels: np.ndarray,
               settings: PlanSettings) -> tuple[list[Obstacle], list[np.ndarray]]:
    """Boxes (map-axis bounds of each blob, for the acoustics' absorption) and prisms (each blob's
    outline in map metres, for the camera)."""
    parts, count = ndimage.label(furniture, structure=np.ones((3, 3)))
    obstacles, prisms = [], []
    for sl_index, window in enumerate(ndimage.find_objects(parts), start=1):
        rows, cols = np.nonzero(parts[window] == sl_index)
        rows, cols = rows + window[0].start, cols + window[1].start
        corners = plan.cell_centres(np.concatenate([cols - 0.5, cols + 0.5, cols - 0.5, cols + 0.5]),
                                    np.concatenate([rows - 0.5, rows - 0.5, rows + 0.5, rows + 0.5]))
        lo, hi = corners.min(axis=0), corners.max(axis=0)
        obstacles.append(Obstacle(xmin=round(float(lo[0]), 4), ymin=round(float(lo[1]), 4),
                                  xmax=round(float(hi[0]), 4), ymax=round(float(hi[1]), 4),
                                  height=float(settings.furniture_height), material=settings.furniture_material))
        prisms.append(_hull(corners))
    return obstacles, prisms


def _hull(points: np.ndarray) -> np.ndarray:
    from scipy.spatial import ConvexHull

    return points[ConvexHull(points).vertices]


def _lattice(free: np.ndarray, labels: np.ndarray, plan: OccupancyGrid, settings: PlanSettings,
             what: str) -> tuple[NavGrid, tuple[int, ...]]:
    """Nodes where the robot fits, edges where it can drive from one to the next; the largest part.

    A wall or a door jamb on a lattice line can cut a building in two that a lattice shifted by a
    fraction of its spacing connects, so the lattice is laid at LATTICE_PHASES offsets (in x and y)
    and the one that connects the building best is kept (``_connectivity``; then the smallest offset).
    """
    res = plan.resolution
    # Clearance of a cell centre: distance to the nearest blocked cell's edge.
    clearance = ndimage.distance_transform_edt(free) * res - res / 2
    candidates = []
    for phase_x in LATTICE_PHASES:
        for phase_y in LATTICE_PHASES:
            graph = _lattice_graph(clearance, plan, settings, (phase_x, phase_y))
            if graph is not None:
                candidates.append(graph)
    if not candidates:
        raise ConfigError(f"{what}: no place has {settings.robot_radius} m of clearance for the robot on a "
                          f"{settings.lattice_spacing} m lattice; lower robot_radius or lattice_spacing")
    cells, origin, edges, part, sizes = max(candidates, key=lambda g: _connectivity(g, labels, plan, settings))
    keep = int(np.argmax(sizes))
    dropped = tuple(sorted((int(s) for k, s in enumerate(sizes) if k != keep), reverse=True))
    kept = np.flatnonzero(part == keep)
    kept_cells = cells[kept]
    order = np.lexsort((kept_cells[:, 0], kept_cells[:, 1]))  # row-major, as generated scenes
    kept, kept_cells = kept[order], kept_cells[order]
    old_of_cell = {tuple(c): int(old) for c, old in zip(kept_cells.tolist(), kept)}

    def can_cross(a, b) -> bool:
        key = (old_of_cell[tuple(a)], old_of_cell[tuple(b)])
        return (min(key), max(key)) in edges

    spacing = settings.lattice_spacing
    ix, iy = plan.cell_of(np.asarray(origin) + (kept_cells + 0.5) * spacing)
    grid = NavGrid(kept_cells, labels[iy, ix] - 1, can_cross, spacing=spacing, origin=origin)
    return grid, dropped


def _connectivity(graph, labels: np.ndarray, plan: OccupancyGrid, settings: PlanSettings) -> tuple:
    """How well a lattice serves the building, best first: rooms its largest part reaches, pairs of
    rooms it passes between (doors used), then its nodes and edges."""
    cells, origin, edges, part, sizes = graph
    keep = int(np.argmax(sizes))
    ix, iy = plan.cell_of(np.asarray(origin) + (cells + 0.5) * settings.lattice_spacing)
    room = labels[iy, ix]
    inside = part == keep
    doors = {(min(room[a], room[b]), max(room[a], room[b])) for a, b in edges if inside[a] and room[a] != room[b]}
    return len(set(room[inside].tolist())), len(doors), int(sizes[keep]), len(edges)


def _lattice_graph(clearance: np.ndarray, plan: OccupancyGrid, settings: PlanSettings, phase):
    """The lattice at one offset: (cells (N, 2), origin, edge set, component of each node, component
    sizes), or None where no node fits."""
    res, spacing, radius = plan.resolution, settings.lattice_spacing, settings.robot_radius
    rows, cols = clearance.shape
    corners = plan.cell_centres(np.array([-0.5, cols - 0.5, -0.5, cols - 0.5]),
                                np.array([-0.5, -0.5, rows - 0.5, rows - 0.5]))
    shift = np.asarray(phase) * spacing
    lo = np.floor((corners.min(axis=0) - shift) / spacing).astype(np.int64) - 1
    hi = np.ceil((corners.max(axis=0) - shift) / spacing).astype(np.int64)
    origin = tuple(float(v) for v in lo * spacing + shift)
    gx, gy = np.meshgrid(np.arange(hi[0] - lo[0]), np.arange(hi[1] - lo[1]), indexing="ij")
    cells = np.stack([gx.ravel(), gy.ravel()], axis=1)
    points = np.asarray(origin) + (cells + 0.5) * spacing

    def clear(xy: np.ndarray) -> np.ndarray:
        ix, iy = plan.cell_of(xy)
        inside = (ix >= 0) & (ix < cols) & (iy >= 0) & (iy < rows)
        value = np.full(ix.shape, -np.inf)
        value[inside] = clearance[iy[inside], ix[inside]]
        return value

    ok = clear(points) >= radius
    cells, points = cells[ok], points[ok]
    if len(cells) == 0:
        return None
    index = {tuple(c): n for n, c in enumerate(cells.tolist())}
    samples = np.linspace(0.0, 1.0, max(3, int(np.ceil(spacing / (res / 2))) + 1))
    src, dst = [], []
    for step in HEADING_STEPS[:2].tolist():  # +x and +y; the graph is undirected
        other = np.array([index.get(tuple(t), -1) for t in (cells + step).tolist()])
        has = np.flatnonzero(other >= 0)
        if len(has) == 0:
            continue
        a, b = points[has], points[other[has]]
        path = a[:, None, :] + samples[None, :, None] * (b - a)[:, None, :]
        fits = (clear(path.reshape(-1, 2)).reshape(len(has), -1) >= radius).all(axis=1)
        # Not straight: connected all the same where the robot gets round (a door off the lattice line)
        # on a path at most DETOUR times the spacing, as SoundSpaces links nodes by navmesh geodesics.
        for k in np.flatnonzero(~fits):
            fits[k] = _drive_length(clearance >= radius, plan, a[k], b[k]) <= DETOUR * spacing
        src += has[fits].tolist()
        dst += other[has][fits].tolist()
    n = len(cells)
    n_parts, part = connected_components(csr_matrix((np.ones(len(src)), (src, dst)), shape=(n, n)), directed=False)
    edges = {(min(a, b), max(a, b)) for a, b in zip(src, dst)}
    return cells, origin, edges, part, np.bincount(part, minlength=n_parts)


def _drive_length(fits: np.ndarray, plan: OccupancyGrid, a: np.ndarray, b: np.ndarray) -> float:
    """Metres of the shortest 8-connected path from ``a`` to ``b`` over cells where the robot fits,
    searched in a window around the two (inf: none)."""
    from skimage.graph import MCP_Geometric

    (ia, ib), (ja, jb) = plan.cell_of(np.stack([a, b]))
    margin = int(np.ceil(DETOUR * np.hypot(*(b - a)) / plan.resolution / 2))
    r0, r1 = max(min(ja, jb) - margin, 0), min(max(ja, jb) + margin + 1, fits.shape[0])
    c0, c1 = max(min(ia, ib) - margin, 0), min(max(ia, ib) + margin + 1, fits.shape[1])
    window = fits[r0:r1, c0:c1]
    if not (window[ja - r0, ia - c0] and window[jb - r0, ib - c0]):
        return np.inf
    costs, _ = MCP_Geometric(np.where(window, 1.0, np.inf)).find_costs([(ja - r0, ia - c0)], [(jb - r0, ib - c0)])
    return float(costs[jb - r0, ib - c0]) * plan.resolution


# ----------------------------------------------------------------------------- camera mesh


def _surfaces_mesh(rooms: list[Room], surfaces: list[Surface], prisms: list[np.ndarray],
                   settings: PlanSettings) -> TriangleMesh:
    """Triangles of the walls, lintels, floors (checkered per 1 m, the generated scenes' motion cue),
    ceilings and furniture, in the generated scenes' palette."""
    from shapely.geometry import Polygon, box

    vertices, faces, colors = [], [], []

    def add(points3d: np.ndarray, triangles: np.ndarray, color) -> None:
        base = sum(len(v) for v in vertices)
        vertices.append(np.asarray(points3d, np.float64))
        faces.append(np.asarray(triangles, np.int64) + base)
        colors.append(np.tile(np.asarray(color, np.float32), (len(triangles), 1)))

    for face in surfaces:
        color = np.asarray(rooms[face.room].color)
        corners = np.asarray(face.corners, np.float64)
        if face.outward[2] == 0:  # walls: darker the more they face along x, as the exact renderer
            add(corners, [[0, 1, 2], [0, 2, 3]], color * (1.0 - 0.18 * abs(face.outward[0])))
        elif face.outward[2] > 0:
            add(*_triangulate(corners[:, :2], corners[0, 2]), 0.25 * color + 0.69)
        else:
            floor = Polygon(corners[:, :2]).buffer(0)
            x0, y0, x1, y1 = np.floor(floor.bounds).astype(int) + [0, 0, 1, 1]
            for cx in range(x0, x1):
                for cy in range(y0, y1):
                    piece = floor.intersection(box(cx, cy, cx + 1, cy + 1))
                    shade = 1.0 if (cx + cy) % 2 == 0 else 0.9
                    for poly in getattr(piece, "geoms", [piece]):
                        if poly.geom_type == "Polygon" and poly.area > 1e-9:
                            add(*_triangulate(np.asarray(poly.exterior.coords)[:-1], 0.0),
                                shade * (0.55 * color + 0.45 * 0.35))
    top = settings.furniture_height
    for outline in prisms:
        k = len(outline)
        bottom, upper = np.column_stack([outline, np.zeros(k)]), np.column_stack([outline, np.full(k, top)])
        sides = [[i, (i + 1) % k, k + (i + 1) % k] for i in range(k)] + \
                [[i, k + (i + 1) % k, k + i] for i in range(k)]
        add(np.vstack([bottom, upper]), sides, OBSTACLE_COLOR)
        add(*_triangulate(outline, top), np.multiply(OBSTACLE_COLOR, 1.4))
    return TriangleMesh(np.vstack(vertices), np.vstack(faces), np.vstack(colors))


def _triangulate(polygon: np.ndarray, z: float) -> tuple[np.ndarray, np.ndarray]:
    """(K, 3) corners at height z and (T, 3) triangles of a simple polygon (ear clipping)."""
    import mapbox_earcut

    polygon = np.asarray(polygon, np.float64)
    triangles = mapbox_earcut.triangulate_float64(polygon, np.array([len(polygon)], np.uint32))
    return np.column_stack([polygon, np.full(len(polygon), z)]), np.asarray(triangles).reshape(-1, 3)
