"""Worlds built from a robot's nav2 map: rooms, furniture, walls, lintels and the lattice of the scripted
apartment (also turned in the map frame), narrow gaps against the robot's radius, every map mode, bad maps,
and what the acoustics, the episodes and the camera make of such a world."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
import shapely
from shapely.geometry import Polygon

from m2h_ros.core.world import plan_world
from m2h_ros.core.world.acoustics import N_HEADINGS, _walls_crossed, room_rt60, simulate_source
from m2h_ros.core.world.camera import CameraConfig, CameraViews
from m2h_ros.core.world.episodes import EpisodeConfig, episode_path, episodes_for
from m2h_ros.core.world.frames import FREE, OCCUPIED, OccupancyGrid, occupancy_grid
from m2h_ros.core.world.navgrid import HEADING_STEPS
from m2h_ros.core.world.plan_world import PlanSettings, build_plan_world
from m2h_ros.core.world.ros_map import read_ros_map
from m2h_ros.core.world.sample_worlds import (APARTMENT_DOORS, APARTMENT_FURNITURE, APARTMENT_ROOMS,
                                              apartment_grid, apartment_to_map, corridor_grid)
from m2h_ros.core.world.worlds import load_world, load_world_with_report
from m2h_ros.errors import ConfigError
from plan_maps import box_grid, map_spec, plan_grid

YAW = math.radians(30)


def centre(rect) -> np.ndarray:
    return np.array([(rect[0] + rect[2]) / 2, (rect[1] + rect[3]) / 2])


def inside(rect, xy, *, margin: float = 0.0) -> bool:
    return rect[0] - margin <= xy[0] <= rect[2] + margin and rect[1] - margin <= xy[1] <= rect[3] + margin


def room_index(scene, name: str, *, yaw: float = 0.0) -> int:
    """The world's room holding the centre of the apartment's room ``name``."""
    return scene.room_at(apartment_to_map(centre(APARTMENT_ROOMS[name]), yaw=yaw))


def lattice_edges(grid) -> list[tuple[int, int]]:
    """Each undirected lattice edge once."""
    return sorted({(min(n, int(m)), max(n, int(m))) for n in range(grid.n_nodes) for m in grid.forward[n]
                   if m != n})


@pytest.fixture(scope="module")
def maps(tmp_path_factory) -> Path:
    return tmp_path_factory.mktemp("plan_worlds")


@pytest.fixture(scope="module")
def apartment(maps):
    """(spec, scene, report) of the clean apartment, read from its nav2 map."""
    spec = map_spec(maps / "apartment", apartment_grid())
    return (spec, *load_world_with_report(spec))


@pytest.fixture(scope="module")
def rotated(maps):
    """(scene, report) of the apartment on a grid turned 30 degrees in the map frame, the world kept in the
    map's frame (``lattice_yaw: 0``: the lattice along the map's axes, not the walls)."""
    (maps / "rotated").mkdir()
    (maps / "rotated" / "map.world.yaml").write_text("lattice_yaw: 0\n")
    return load_world_with_report(map_spec(maps / "rotated", apartment_grid(yaw=YAW)))


@pytest.fixture(scope="module")
def fine_apartment(maps):
    """The apartment on a 0.5 m lattice (Replica's spacing)."""
    folder = maps / "fine"
    spec = map_spec(folder, apartment_grid())
    (folder / "map.world.yaml").write_text("lattice_spacing: 0.5\n")
    return load_world(spec)


# --- the apartment -----------------------------------------------------------------------------------

def test_the_apartments_six_rooms_have_the_plans_areas(apartment):
    _, scene, report = apartment
    assert scene.imported and scene.source == "map" and len(scene.rooms) == 6
    indices = {name: room_index(scene, name) for name in APARTMENT_ROOMS}
    assert sorted(indices.values()) == list(range(6))  # each plan room is a room of its own
    for name, rect in APARTMENT_ROOMS.items():
        planned = (rect[2] - rect[0]) * (rect[3] - rect[1])  # the doorways add a little to it
        assert scene.rooms[indices[name]].area == pytest.approx(planned, rel=0.03), name
    assert [area for _, area in report.rooms] == [room.area for room in scene.rooms]


def test_the_furniture_stands_where_the_plan_puts_it(apartment):
    _, scene, report = apartment
    assert len(scene.obstacles) == report.n_furniture == len(APARTMENT_FURNITURE)
    boxes = {(o.xmin, o.ymin, o.xmax, o.ymax) for o in scene.obstacles}
    for name, rect in APARTMENT_FURNITURE.items():
        box = min(boxes, key=lambda b: np.hypot(*(centre(b) - centre(rect))))
        np.testing.assert_allclose(box, rect, atol=0.051, err_msg=name)  # a cell of the raster
        assert scene.obstacles[0].height == PlanSettings().furniture_height
    # The furniture blocks the robot: no node on it.
    for o in scene.obstacles:
        assert not any(o.xmin <= x <= o.xmax and o.ymin <= y <= o.ymax for x, y in scene.grid.positions)


def test_every_node_stands_in_a_room_with_the_robots_clearance(apartment):
    spec, scene, _ = apartment
    grid, radius = scene.grid, PlanSettings().robot_radius
    plan = read_ros_map(spec[len("map:"):]).grid
    rows, cols = np.nonzero(plan.cells != FREE)
    blocked = plan.cell_centres(cols, rows)
    nearest = np.sqrt(((grid.positions[:, None, :] - blocked[None]) ** 2).sum(-1)).min(axis=1)
    # A node's distance to the nearest blocked cell's centre, less half a cell: to that cell's edge.
    assert nearest.min() >= radius + plan.resolution / 2 - plan.resolution / math.sqrt(2)
    assert [scene.room_at(p) for p in grid.positions] == grid.room_of.tolist()
    assert (grid.room_of >= 0).all()


def test_the_lattice_is_one_part_that_reaches_every_room(apartment):
    _, scene, report = apartment
    grid = scene.grid
    assert report.dropped_components == () and report.n_nodes == grid.n_nodes
    assert grid.n_components == 1 and np.isfinite(grid.geodesic).all()
    assert set(grid.room_of.tolist()) == set(range(len(scene.rooms)))
    assert grid.spacing == 1.0


def test_lattice_edges_between_rooms_pass_through_doors(apartment, fine_apartment):
    for scene in (apartment[1], fine_apartment):
        grid = scene.grid
        crossings = [(a, b) for a, b in lattice_edges(grid) if grid.room_of[a] != grid.room_of[b]]
        assert crossings
        for a, b in crossings:
            middle = (grid.positions[a] + grid.positions[b]) / 2
            assert any(inside(rect, middle, margin=grid.spacing / 2) for rect in APARTMENT_DOORS.values()), \
                (grid.positions[a], grid.positions[b])
    # On the 0.5 m lattice every door is crossed by an edge between the two rooms it joins.
    grid = fine_apartment.grid
    joined = {frozenset((int(grid.room_of[a]), int(grid.room_of[b]))) for a, b in lattice_edges(grid)}
    for rooms in APARTMENT_DOORS:
        assert frozenset(room_index(fine_apartment, name) for name in rooms) in joined, rooms


def test_a_lintel_spans_each_door_from_door_height_to_the_ceiling(apartment):
    _, scene, _ = apartment
    settings = PlanSettings()
    assert len(scene.doors) == len(APARTMENT_DOORS)
    for lintel in scene.doors:
        assert lintel.z0 == settings.door_height and lintel.z1 == scene.height == settings.wall_height
        middle = (np.asarray(lintel.p0) + np.asarray(lintel.p1)) / 2
        door = next(pair for pair, rect in APARTMENT_DOORS.items() if inside(rect, middle))
        assert set(lintel.rooms) == {room_index(scene, name) for name in door}
        assert np.hypot(*np.subtract(lintel.p1, lintel.p0)) == pytest.approx(0.8, abs=0.1)
    # Both rooms see the lintel: a face on each side, the plain walls below it are not there.
    lintel_faces = [s for s in scene.surfaces if s.outward[2] == 0 and s.corners[0][2] == settings.door_height]
    assert len(lintel_faces) == 2 * len(APARTMENT_DOORS)


def test_each_room_has_a_floor_and_a_ceiling_over_its_cells(apartment):
    _, scene, _ = apartment
    plan, tolerance = scene.plan, PlanSettings().wall_tolerance
    for index, room in enumerate(scene.rooms):
        flats = [s for s in scene.surfaces if s.room == index and s.outward[2] != 0]
        floors = [s for s in flats if s.outward[2] < 0]
        ceilings = [s for s in flats if s.outward[2] > 0]
        assert len(floors) == len(ceilings) == 1
        assert {c[2] for c in floors[0].corners} == {0.0} and {c[2] for c in ceilings[0].corners} == {scene.height}
        assert [c[:2] for c in floors[0].corners] == [c[:2] for c in ceilings[0].corners]
        mine = scene.room_labels == index
        assert mine.sum() * plan.resolution ** 2 == pytest.approx(room.area)
        floor = Polygon([c[:2] for c in floors[0].corners])
        rows, cols = np.indices(mine.shape)
        covered = shapely.contains_xy(floor, *plan.cell_centres(cols, rows).transpose(2, 0, 1))
        # The outline keeps within wall_tolerance of the room's cells, so it covers them up to a strip
        # that wide along its length.
        assert floor.is_valid and (covered != mine).sum() * plan.resolution ** 2 <= floor.length * tolerance
        assert floor.equals(Polygon(room.polygon))


def test_wall_faces_point_away_from_their_room(apartment):
    _, scene, _ = apartment
    walls = [s for s in scene.surfaces if s.outward[2] == 0]
    assert len(walls) >= 4 * len(scene.rooms)
    for face in walls:
        corners = np.asarray(face.corners)
        middle, normal = corners[:2, :2].mean(axis=0), np.asarray(face.outward[:2])
        assert np.hypot(*normal) == pytest.approx(1.0)
        assert np.dot(normal, corners[1, :2] - corners[0, :2]) == pytest.approx(0.0, abs=1e-9)
        assert scene.room_at(middle - 0.2 * normal) == face.room, face
        assert scene.room_at(middle + 0.2 * normal) != face.room, face


def test_a_ragged_slam_map_gives_the_same_rooms_furniture_and_doors(maps, apartment):
    _, clean, _ = apartment
    scene, report = load_world_with_report(map_spec(maps / "slam", apartment_grid(noise=0.3, seed=1)))
    assert len(scene.rooms) == 6 and report.n_furniture == len(APARTMENT_FURNITURE)
    assert len(scene.doors) == len(APARTMENT_DOORS) and report.dropped_components == ()
    for name in APARTMENT_ROOMS:  # walls only grow into the rooms, by a cell or two
        area, plain = scene.rooms[room_index(scene, name)].area, clean.rooms[room_index(clean, name)].area
        assert 0.97 * plain < area < plain, name
    assert set(scene.grid.room_of.tolist()) == set(range(6))


# --- the apartment turned in the map frame -------------------------------------------------------------

def test_a_turned_map_gives_the_same_rooms_and_furniture(apartment, rotated):
    _, upright, _ = apartment
    scene, report = rotated
    assert len(scene.rooms) == len(upright.rooms) and report.n_furniture == len(APARTMENT_FURNITURE)
    for name in APARTMENT_ROOMS:
        turned, plain = scene.rooms[room_index(scene, name, yaw=YAW)], upright.rooms[room_index(upright, name)]
        assert turned.area == pytest.approx(plain.area, rel=0.01), name
    # Furniture boxes are map-axis bounds of the turned blobs: centred where the plan's are, turned.
    centres = np.array([centre((o.xmin, o.ymin, o.xmax, o.ymax)) for o in scene.obstacles])
    for name, rect in APARTMENT_FURNITURE.items():
        assert np.hypot(*(centres - apartment_to_map(centre(rect), yaw=YAW)).T).min() < 0.1, name
    assert all(size < scene.grid.n_nodes for size in report.dropped_components)  # the largest part is kept
    xmin, ymin, xmax, ymax = scene.bounds
    x, y = scene.grid.positions.T
    assert ((x > xmin) & (x < xmax) & (y > ymin) & (y < ymax)).all()
    assert [scene.room_at(p) for p in scene.grid.positions] == scene.grid.room_of.tolist()


def test_a_turned_map_gets_its_lattice_along_its_walls(maps, apartment):
    _, upright, _ = apartment
    scene, report = load_world_with_report(map_spec(maps / "turned", apartment_grid(yaw=YAW)))
    assert report.turn_deg == pytest.approx(math.degrees(YAW), abs=0.5)
    # The world's frame is the map's turned back: the building as upright as the plan, all of it reached.
    assert report.dropped_components == () and set(scene.grid.room_of.tolist()) == set(range(len(scene.rooms)))
    assert scene.grid.n_nodes >= 0.9 * upright.grid.n_nodes
    assert occupancy_grid(scene).yaw == pytest.approx(0.0, abs=math.radians(0.5))
    back = np.array([[math.cos(YAW), math.sin(YAW)], [-math.sin(YAW), math.cos(YAW)]])  # map -> world frame
    for name in APARTMENT_ROOMS:
        index = scene.room_at(back @ apartment_to_map(centre(APARTMENT_ROOMS[name]), yaw=YAW))
        assert scene.rooms[index].area == pytest.approx(upright.rooms[room_index(upright, name)].area, rel=0.01), name


def test_the_published_map_of_a_map_world_is_its_own_grid(apartment, rotated):
    scene, _ = rotated
    published = occupancy_grid(scene)
    expected = apartment_grid(yaw=YAW)
    assert published.yaw == pytest.approx(YAW) and published.resolution == expected.resolution
    np.testing.assert_allclose(published.origin, expected.origin)
    np.testing.assert_array_equal(published.cells, expected.cells)
    _, upright, _ = apartment
    assert occupancy_grid(upright).yaw == 0.0 and occupancy_grid(upright).cells.shape == expected.cells.shape


# --- the lattice and the robot ----------------------------------------------------------------------------

@pytest.mark.parametrize("width, crossed", [(0.35, False), (0.8, True)])
def test_a_corridor_narrower_than_the_robot_is_not_crossed(maps, width, crossed):
    scene, report = load_world_with_report(map_spec(maps / f"corridor_{width}", corridor_grid(width)))
    rooms = set(scene.grid.room_of.tolist())
    assert len(scene.rooms) == 2 and scene.grid.n_components == 1
    if crossed:
        assert rooms == {0, 1} and report.dropped_components == ()
    else:  # one room's nodes kept, the other's reported as left out
        assert len(rooms) == 1 and len(report.dropped_components) == 1
        assert report.dropped_components[0] == scene.grid.n_nodes  # two rooms of the same size
        assert "left out 1 unconnected lattice part" in report.describe()


def two_rooms_with_a_door(door_from: float) -> OccupancyGrid:
    """Rooms [0, 3] and [3.1, 6.1] x [0, 3] m, a 0.8 m door from y = ``door_from`` in the wall between."""
    return plan_grid([(0.0, 0.0, 3.0, 3.0), (3.1, 0.0, 6.1, 3.0), (2.9, door_from, 3.2, door_from + 0.8)],
                     footprint=(-0.1, -0.1, 6.2, 3.1))


def test_a_door_off_the_lattice_line_is_crossed_by_a_detour(monkeypatch):
    # Lattice lines at y = 0.5, 1.5, 2.5 (offset 0); the door spans 1.6..2.4, so no straight edge
    # keeps 0.2 m from its jambs, but the robot gets round them on a path under DETOUR x 1 m.
    plan = two_rooms_with_a_door(1.6)

    def build():
        return build_plan_world(plan, free=plan.cells == FREE, occupied=plan.cells == OCCUPIED,
                                settings=PlanSettings(), scene_id="door", source="map", fingerprint="0", what="test")

    phases = plan_world.LATTICE_PHASES
    monkeypatch.setattr(plan_world, "LATTICE_PHASES", (0.0,))
    scene, report = build()
    assert set(scene.grid.positions[:, 1].tolist()) == {0.5, 1.5, 2.5}
    assert set(scene.grid.room_of.tolist()) == {0, 1} and report.dropped_components == ()
    monkeypatch.setattr(plan_world, "DETOUR", 1.0)  # straight edges only: the rooms fall apart
    _, report = build()
    assert len(report.dropped_components) == 1
    # Straight edges only, but the lattice may shift: the offset that puts a line through the door wins.
    monkeypatch.setattr(plan_world, "LATTICE_PHASES", phases)
    scene, report = build()
    assert set(scene.grid.room_of.tolist()) == {0, 1} and report.dropped_components == ()
    assert any(1.8 <= y <= 2.2 for y in scene.grid.positions[:, 1])


def test_a_room_under_min_room_area_joins_its_neighbour():
    # A 1.2 x 1.2 m closet off a 4 x 3 m room through a 0.8 m door.
    plan = plan_grid([(0.0, 0.0, 4.0, 3.0), (4.1, 0.0, 5.3, 1.2), (3.9, 0.2, 4.3, 1.0)],
                     footprint=(-0.1, -0.1, 5.4, 3.1))

    def rooms(min_room_area: float) -> list[float]:
        scene, _ = build_plan_world(plan, free=plan.cells == FREE, occupied=plan.cells == OCCUPIED,
                                    settings=PlanSettings(min_room_area=min_room_area), scene_id="closet",
                                    source="map", fingerprint="0", what="test")
        assert scene.room_at((4.7, 0.6)) >= 0  # the closet is floor of some room
        return sorted(room.area for room in scene.rooms)

    closet, room = rooms(1.0)
    assert closet == pytest.approx(1.44, rel=0.1) and room == pytest.approx(12.0, rel=0.03)
    assert rooms(2.0) == [pytest.approx(closet + room)]


def test_half_metre_lattice_has_four_times_the_nodes_and_metre_geodesics(apartment, fine_apartment):
    coarse, fine = apartment[1].grid, fine_apartment.grid
    assert fine.spacing == 0.5 and 3.3 < fine.n_nodes / coarse.n_nodes < 4.5
    assert fine.n_components == 1
    for grid in (coarse, fine):
        for a, b in lattice_edges(grid):
            assert np.hypot(*(grid.positions[a] - grid.positions[b])) == pytest.approx(grid.spacing)
            assert grid.geodesic[a, b] == pytest.approx(grid.spacing)
    # The living room's longest straight run of nodes along +x: k moves, k * 0.5 m.
    living = room_index(fine_apartment, "living_room")
    start = min(np.flatnonzero(fine.room_of == living), key=lambda n: tuple(fine.positions[n][::-1]))
    run = [int(start)]
    while (nxt := int(fine.forward[run[-1], 0])) != run[-1]:
        run.append(nxt)
    assert len(run) >= 8
    assert fine.geodesic[run[0], run[-1]] == pytest.approx((len(run) - 1) * 0.5)
    assert len(fine.shortest_path(run[0], run[-1])) == len(run)


# --- every map mode --------------------------------------------------------------------------------

@pytest.mark.parametrize("options", [dict(negate=True), dict(image_format="png"),
                                     dict(mode="scale", image_format="png"), dict(mode="raw")],
                         ids=["negate", "png", "scale", "raw"])
def test_every_mode_gives_the_same_world_of_the_same_plan(maps, apartment, options):
    _, expected, _ = apartment
    name = "_".join(f"{k}-{v}" for k, v in options.items())
    scene = load_world(map_spec(maps / name, apartment_grid(), **options))
    assert [r.area for r in scene.rooms] == [r.area for r in expected.rooms]
    np.testing.assert_array_equal(scene.grid.positions, expected.grid.positions)
    assert scene.surfaces == expected.surfaces and scene.walls == expected.walls
    assert scene.obstacles == expected.obstacles
    np.testing.assert_array_equal(scene.room_labels, expected.room_labels)


# --- maps that make no world -----------------------------------------------------------------------

def test_maps_without_a_closed_free_space_are_refused(maps):
    solid = OccupancyGrid(np.full((40, 40), OCCUPIED, np.int8), 0.05, (0.0, 0.0))
    spec = map_spec(maps / "solid", solid)
    with pytest.raises(ConfigError, match=r"solid/map\.yaml has no free space.*negate, free_thresh"):
        load_world(spec)
    open_floor = np.full((40, 40), FREE, np.int8)
    open_floor[15:25, 15:25] = OCCUPIED
    spec = map_spec(maps / "open", OccupancyGrid(open_floor, 0.05, (0.0, 0.0)))
    with pytest.raises(ConfigError, match=r"open/map\.yaml: free space runs off the edge"):
        load_world(spec)


def test_a_robot_too_big_for_every_place_is_refused(maps):
    folder = maps / "big_robot"
    spec = map_spec(folder, box_grid(3.0, 2.0))
    (folder / "map.world.yaml").write_text("robot_radius: 1.2\n")
    with pytest.raises(ConfigError, match=r"big_robot/map\.yaml: no place has 1\.2 m of clearance.*lower robot_radius"):
        load_world(spec)


# --- acoustics, episodes and the camera in a map world ---------------------------------------------------

def test_apartment_rooms_reverberate_like_furnished_rooms(apartment):
    _, scene, _ = apartment
    for index in range(len(scene.rooms)):
        rt60 = room_rt60(scene, index)
        assert ((rt60 > 0.2) & (rt60 < 1.0)).all(), (scene.rooms[index].name, rt60)


def test_a_thick_wall_is_crossed_once(apartment):
    _, scene, _ = apartment
    start = np.array([*apartment_to_map([1.0, 3.0]), 1.5])  # living room, 0.95 m below its wall to the hallway
    ends = np.array([[1.0, 4.6, 1.5],   # hallway: through the living room's wall
                     [1.0, 6.0, 1.5],   # bedroom 1: through that wall and the hallway's
                     [1.0, 1.0, 1.5]])  # the same room
    np.testing.assert_array_equal(_walls_crossed(scene, start, ends, 1.5), [1, 2, 0])
    # Above the doors only the lintels and walls span; at 2.3 m a path through a lintel counts it once.
    door = centre(APARTMENT_DOORS[("living_room", "hallway")])
    through_lintel = _walls_crossed(scene, np.array([door[0], 3.3, 2.3]), np.array([[door[0], 4.7, 2.3]]), 2.3)
    assert through_lintel.tolist() == [1]
    under_lintel = _walls_crossed(scene, np.array([door[0], 3.3, 1.5]), np.array([[door[0], 4.7, 1.5]]), 1.5)
    assert under_lintel.tolist() == [0]


def test_sound_is_louder_in_the_sources_room_than_behind_two_walls(apartment, fast_acoustics):
    _, scene, _ = apartment
    grid = scene.grid
    source = grid.nearest_node(apartment_to_map([1.5, 2.5]))  # living room
    rows = simulate_source(scene, source, fast_acoustics)
    assert rows.shape == (grid.n_nodes, fast_acoustics.row_length) and np.isfinite(rows).all()
    early = (rows[:, : N_HEADINGS * 2 * fast_acoustics.n_early].astype(np.float64) ** 2).sum(axis=1)
    points = np.column_stack([grid.positions, np.full(grid.n_nodes, fast_acoustics.head_height)])
    walls = _walls_crossed(scene, points[source], points, fast_acoustics.head_height)
    distance = np.hypot(*(grid.positions - grid.positions[source]).T)
    same = [n for n in range(grid.n_nodes) if n != source and grid.room_of[n] == grid.room_of[source]]
    behind = np.flatnonzero(walls == 2)
    pairs = [(a, b) for a in same for b in behind if abs(distance[a] - distance[b]) <= 0.5]
    assert len(pairs) >= 3
    for a, b in pairs:
        assert early[a] > 5 * early[b], (grid.positions[a], grid.positions[b], early[a], early[b])


def test_episodes_of_a_map_world_stand_on_its_nodes(apartment, folder_library, tmp_path, monkeypatch):
    spec, scene, _ = apartment
    monkeypatch.setenv("M2H_DATA_DIR", str(tmp_path))
    for task in ("near_target", "far_target"):
        config = EpisodeConfig(task=task, scene_split=spec, count=12, seed=2)
        episodes = episodes_for(config, folder_library)
        path = episode_path(config, folder_library)
        assert path.exists() and scene.fingerprint() in path.name
        geodesic = scene.grid.geodesic
        for episode in episodes:
            assert episode.scene().fingerprint() == scene.fingerprint()
            assert episode.scene_id == scene.world_id == f"apartment@{scene.fingerprint()}"
            assert episode.episode_id.startswith(f"map-apartment-{scene.fingerprint()}/{task}/")
            assert all(0 <= n < scene.grid.n_nodes for n in (*episode.source_nodes, episode.start_node))
            assert geodesic[episode.source_nodes[0], episode.source_nodes[1]] >= config.min_source_distance
            to_target = geodesic[episode.start_node, episode.target_node]
            assert 0 < to_target <= config.near_radius if task == "near_target" else \
                to_target >= config.far_min_distance


def distance_to_walls(scene, origin, direction) -> float:
    """Metres along ``direction`` from ``origin`` to the nearest wall of ``scene`` (in plan)."""
    best = np.inf
    for wall in scene.walls:
        p0, p1 = np.asarray(wall.p0), np.asarray(wall.p1)
        matrix = np.column_stack([direction, p0 - p1])
        if abs(np.linalg.det(matrix)) > 1e-12:
            t, u = np.linalg.solve(matrix, p0 - origin)
            if t > 0 and 0 <= u <= 1:
                best = min(best, t)
    return best


def test_the_camera_sees_the_wall_ahead_at_its_distance(maps):
    scene = load_world(map_spec(maps / "box", box_grid(4.0, 3.0)))
    views = CameraViews(scene, CameraConfig())
    node = scene.grid.nearest_node([1.5, 1.5])
    x, y = scene.grid.positions[node]
    wall_ahead = {0: 4.0 - x, 1: 3.0 - y, 2: x, 3: y}  # the floor's inner faces at x = 0, 4 and y = 0, 3
    for heading, distance in wall_ahead.items():
        rgb, depth = views.view(node, heading)
        assert rgb.shape == (128, 128, 3) and rgb.dtype == np.uint8 and depth.shape == (128, 128)
        traced = distance_to_walls(scene, scene.grid.positions[node], HEADING_STEPS[heading])
        np.testing.assert_allclose(depth[63:65, 63:65], traced, atol=0.002)
        # The traced wall keeps within half a plan cell of the room's true wall.
        assert traced == pytest.approx(distance, abs=scene.plan.resolution / 2 + 1e-6)
        assert len(np.unique(rgb.reshape(-1, 3), axis=0)) > 3  # wall, floor and ceiling, shaded
    ahead = scene.grid.forward[node, 0]
    np.testing.assert_allclose(scene.grid.positions[ahead], scene.grid.positions[node] + [scene.grid.spacing, 0])
    assert views.view(ahead, 0)[1][64, 64] == pytest.approx(views.view(node, 0)[1][64, 64] - scene.grid.spacing,
                                                            abs=0.002)
