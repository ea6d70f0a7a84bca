"""Procedural scenes and the navigation grid: connectivity, geodesics, walls vs doors, determinism."""

import dataclasses

import numpy as np
import pytest

from m2h_ros.core.world.navgrid import HEADING_STEPS, NavGrid, turn_left, turn_right
from m2h_ros.core.world.scene import (FURNISHING_WEIGHTS, FURNISHINGS, MATERIALS, SCENE_SPLITS, Scene,
                                      build_scene, cells_outline, generate_scene, isolated_room,
                                      load_split)
from m2h_ros.errors import ConfigError, M2HError

SEEDS = range(12)


@pytest.fixture(scope="module")
def scenes() -> list[Scene]:
    return [generate_scene(seed) for seed in SEEDS]


def _covering_walls(scene: Scene, a, b):
    """Walls whose segment contains the unit lattice edge between 4-adjacent cells a and b."""
    if a[0] != b[0]:   # edge on x = const
        x, y = max(a[0], b[0]), a[1]
        return [w for w in scene.walls if w.p0[0] == w.p1[0] == x and w.p0[1] <= y and y + 1 <= w.p1[1]]
    y, x = max(a[1], b[1]), a[0]
    return [w for w in scene.walls if w.p0[1] == w.p1[1] == y and w.p0[0] <= x and x + 1 <= w.p1[0]]


def test_default_preset_shape(scenes):
    for scene in scenes:
        assert 3 <= len(scene.rooms) <= 5
        assert 30 <= scene.grid.n_nodes <= 60
        assert len(scene.obstacles) >= 1
        assert scene.grid.n_components == 1
        # A rectangle has 4 corners; at least one room is L/T/Z shaped.
        assert max(len(room.outline()) for room in scene.rooms) >= 6
        assert len({room.color for room in scene.rooms}) == len(scene.rooms)
        assert len({room.wall_material for room in scene.rooms}) == len(scene.rooms)
        assert scene.grid.geodesic.shape == (scene.grid.n_nodes,) * 2
        assert np.isfinite(scene.grid.geodesic).all()


def test_materials_exist_in_pyroomacoustics(scenes):
    import pyroomacoustics as pra

    used = {m for s in scenes for r in s.rooms for m in (r.wall_material, r.floor_material,
                                                          r.ceiling_material)}
    used |= {o.material for s in scenes for o in s.obstacles}
    assert used <= set(MATERIALS)
    for name in MATERIALS:
        assert pra.Material(name).absorption_coeffs is not None


def test_geodesic_is_a_metric(scenes):
    for scene in scenes[:4]:
        g = scene.grid.geodesic.astype(np.float64)
        np.testing.assert_array_equal(g, g.T)
        assert (np.diag(g) == 0).all() and (g[~np.eye(len(g), dtype=bool)] >= 1).all()
        # Triangle inequality for all triples: g[i, k] <= g[i, j] + g[j, k].
        assert (g[:, None, :] <= g[:, :, None] + g[None, :, :] + 1e-6).all()
        # Geodesic is never shorter than the straight line between node centres.
        pos = scene.grid.positions
        euclid = np.linalg.norm(pos[:, None] - pos[None], axis=-1)
        assert (g >= euclid - 1e-6).all()


def test_geodesic_equals_manhattan_in_empty_rectangle():
    cells = np.array([(x, y) for y in range(4) for x in range(6)])
    grid = NavGrid(cells, np.zeros(len(cells)), lambda a, b: True)
    manhattan = np.abs(grid.positions[:, None] - grid.positions[None]).sum(-1)
    np.testing.assert_array_equal(grid.geodesic, manhattan.astype(np.float32))
    corner = grid.node_at_cell(0, 0)
    assert grid.forward[corner, 2] == corner and grid.forward[corner, 3] == corner   # grid edge
    assert grid.forward[corner, 0] == grid.node_at_cell(1, 0)
    assert grid.forward[corner, 1] == grid.node_at_cell(0, 1)


def test_forward_blocked_by_walls_and_obstacles_not_by_doors(scenes):
    n_door_moves = 0
    for scene in scenes:
        grid = scene.grid
        for n, cell in enumerate(grid.cells.tolist()):
            for h, step in enumerate(HEADING_STEPS.tolist()):
                target = (cell[0] + step[0], cell[1] + step[1])
                target_node = grid.node_at_cell(*target)
                walls = _covering_walls(scene, cell, target)
                assert len(walls) <= 1
                full_wall = any(w.z0 == 0.0 for w in walls)
                if target_node < 0 or full_wall:
                    assert grid.forward[n, h] == n
                else:
                    assert grid.forward[n, h] == target_node
                    if walls:   # crossing a lintel = walking through a door
                        assert walls[0].z0 == pytest.approx(scene.door_height)
                        assert grid.room_of[target_node] != grid.room_of[n]
                        n_door_moves += 1
    assert n_door_moves > 0


def test_walls_cover_every_room_boundary_and_doors_are_one_metre(scenes):
    for scene in scenes[:4]:
        w, h = scene.size
        edges = [((x - 1, y), (x, y)) for x in range(w + 1) for y in range(h)]
        edges += [((x, y - 1), (x, y)) for y in range(h + 1) for x in range(w)]
        for a, b in edges:
            different = scene.room_at(np.add(a, 0.5)) != scene.room_at(np.add(b, 0.5))
            assert len(_covering_walls(scene, a, b)) == int(different)
        for door in scene.doors:
            assert np.hypot(door.p1[0] - door.p0[0], door.p1[1] - door.p0[1]) == 1.0
            assert -1 not in door.rooms and door.z1 == scene.height
        # Doors join all rooms: the room adjacency through doors is connected (checked via grid).
        assert set(scene.grid.room_of.tolist()) == set(range(len(scene.rooms)))


def test_obstacles_sit_in_cells_without_nodes(scenes):
    for scene in scenes:
        for ob in scene.obstacles:
            cell = (int(np.floor(ob.xmin)), int(np.floor(ob.ymin)))
            assert ob.xmax <= cell[0] + 1 and ob.ymax <= cell[1] + 1 and 0 < ob.height < scene.height
            assert scene.grid.node_at_cell(*cell) == -1
            assert scene.room_at((ob.xmin, ob.ymin)) >= 0


def test_room_at_and_nearest_node(scenes):
    scene = scenes[0]
    grid = scene.grid
    for n in range(grid.n_nodes):
        assert scene.room_at(grid.positions[n]) == grid.room_of[n]
        assert grid.nearest_node(grid.positions[n] + 0.3) == n
    assert scene.room_at((-0.5, 1.0)) == -1 and scene.room_at((scene.size[0] + 0.1, 0.5)) == -1
    np.testing.assert_array_equal(grid.nearest_node(grid.positions[:5] - 0.2), np.arange(5))


def test_turns():
    assert [turn_left(h) for h in range(4)] == [1, 2, 3, 0]
    assert [turn_right(h) for h in range(4)] == [3, 0, 1, 2]


def test_determinism_and_fingerprint_sensitivity():
    a, b = generate_scene(5), generate_scene(5, scene_id="other")
    assert a.fingerprint() == b.fingerprint()
    assert a.walls == b.walls and a.rooms == b.rooms and a.obstacles == b.obstacles
    np.testing.assert_array_equal(a.grid.geodesic, b.grid.geodesic)
    # Fresh generation (bypassing the in-process memo) gives the same scene.
    from m2h_ros.core.world import scene as scene_module
    scene_module._generate.cache_clear()
    assert generate_scene(5).fingerprint() == a.fingerprint()
    fingerprints = {generate_scene(seed).fingerprint() for seed in range(10)}
    assert len(fingerprints) == 10
    assert generate_scene(5, preset="small").fingerprint() != a.fingerprint()
    # A one-material change moves the fingerprint.
    changed = dataclasses.replace(a, rooms=(dataclasses.replace(a.rooms[0], floor_material="marble_floor"
                                  if a.rooms[0].floor_material != "marble_floor" else "concrete_floor"),)
                                  + a.rooms[1:])
    assert changed.fingerprint() != a.fingerprint()
    other = "bare" if a.rooms[0].furnishing != "bare" else "living"
    refurnished = dataclasses.replace(a, rooms=(dataclasses.replace(a.rooms[0], furnishing=other),)
                                      + a.rooms[1:])
    assert refurnished.fingerprint() != a.fingerprint()


def test_rooms_are_furnished(scenes):
    used = [room.furnishing for scene in scenes for room in scene.rooms]
    assert set(used) <= set(FURNISHING_WEIGHTS) and len(set(used)) >= 3
    assert all(FURNISHINGS[name] for name in used)  # generated rooms are never bare
    labels = np.zeros((3, 2), dtype=int)
    assert build_scene(labels).rooms[0].furnishing == "bare"
    with pytest.raises(ConfigError, match="furnishings"):
        build_scene(labels, furnishings=["palace"])


def test_isolated_room_keeps_surfaces_furnishing_and_boxes(scenes):
    scene = scenes[0]
    boxed = next(i for i, room in enumerate(scene.rooms)
                 if any(scene.room_at((o.xmin, o.ymin)) == i for o in scene.obstacles))
    room = isolated_room(scene, boxed)
    assert len(room.rooms) == 1 and room.doors == ()
    assert room.rooms[0].cells == scene.rooms[boxed].cells
    assert dataclasses.replace(room.rooms[0], name=scene.rooms[boxed].name) == scene.rooms[boxed]
    assert room.obstacles == tuple(o for o in scene.obstacles if scene.room_at((o.xmin, o.ymin)) == boxed)
    with pytest.raises(ConfigError):
        isolated_room(scene, len(scene.rooms))


def test_small_preset_is_small():
    # (Its speed: scripts/bench/scene.py.)
    for scene in [generate_scene(seed, preset="small") for seed in range(20)]:
        assert len(scene.rooms) == 2 and 8 <= scene.grid.n_nodes <= 14
        assert scene.grid.n_components == 1 and len(scene.doors) == 1


def test_splits_are_disjoint_and_named():
    # Training, validation and test scenes never share a seed; train24 is train and 12 more, train48 train24
    # and 24 more.
    seeds = [set(SCENE_SPLITS[name]) for name in ("train48", "val", "test")]
    assert sum(len(s) for s in seeds) == len(set().union(*seeds))
    assert SCENE_SPLITS["train24"][:12] == SCENE_SPLITS["train"] and len(SCENE_SPLITS["train24"]) == 24
    assert SCENE_SPLITS["train48"][:24] == SCENE_SPLITS["train24"] and len(set(SCENE_SPLITS["train48"])) == 48
    test = load_split("test")
    assert [s.scene_id for s in test] == [f"test_{i:03d}" for i in range(len(SCENE_SPLITS["test"]))]
    assert [s.seed for s in test] == list(SCENE_SPLITS["test"])


def test_invalid_arguments():
    with pytest.raises(ConfigError, match="preset"):
        generate_scene(0, preset="huge")
    with pytest.raises(ConfigError, match="seed"):
        generate_scene(-1)
    with pytest.raises(ConfigError, match="split"):
        load_split("training")


def test_cells_outline_of_an_l_shape():
    outline = cells_outline([(0, 0), (1, 0), (0, 1)])
    np.testing.assert_array_equal(outline, [[0, 0], [2, 0], [2, 1], [1, 1], [1, 2], [0, 2]])


def test_shortest_path_follows_forward_moves(scenes):
    grid = scenes[1].grid
    far = int(np.argmax(grid.geodesic[0]))
    path = grid.shortest_path(0, far)
    assert path[0] == 0 and path[-1] == far and len(path) - 1 == grid.geodesic[0, far]
    assert all(b in grid.forward[a] and a != b for a, b in zip(path, path[1:]))


def test_build_scene_shoebox_and_bad_doors():
    from m2h_ros.core.world.scene import build_scene
    box = build_scene(np.zeros((5, 4), dtype=int))
    assert len(box.walls) == 4 and box.grid.n_nodes == 20 and not box.doors
    np.testing.assert_array_equal(box.outline(), [[0, 0], [5, 0], [5, 4], [0, 4]])
    labels = np.zeros((4, 2), dtype=int)
    labels[2:] = 1
    with pytest.raises(ConfigError, match="door"):
        build_scene(labels, doors=[((0, 0), (1, 0))])    # same room
    with pytest.raises(M2HError, match="components"):
        build_scene(labels)                              # two rooms, no door
