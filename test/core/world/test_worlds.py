"""World specs (map:PATH, mesh:PATH), the world file beside a map and what its settings do, user rooms,
fingerprints and the memo, and the errors a user meets with a bad map or world file."""

from __future__ import annotations

import os
import shutil
from pathlib import Path

import numpy as np
import pytest
import yaml
from PIL import Image

from m2h_ros.core.world.acoustics import room_rt60
from m2h_ros.core.world.episodes import EpisodeConfig, episode_path, episodes_for
from m2h_ros.core.world.frames import OCCUPIED, OccupancyGrid
from m2h_ros.core.world.plan_world import PlanSettings
from m2h_ros.core.world.sample_worlds import corridor_grid
from m2h_ros.core.world.worlds import (WorldFile, canonical_spec, is_world_spec, load_world, load_world_with_report,
                                       parse_world_spec, read_world_file, world_file_path, worlds_of)
from m2h_ros.errors import ConfigError, EpisodeError, MapError
from plan_maps import box_grid, map_spec

BOX = box_grid(4.0, 3.0)


@pytest.fixture(scope="module")
def box(tmp_path_factory):
    """(spec, world) of a 4 x 3 m room with no world file: every setting at its default."""
    spec = map_spec(tmp_path_factory.mktemp("worlds") / "box", BOX)
    return spec, load_world(spec)


def with_world_file(folder: Path, settings: dict, grid: OccupancyGrid = BOX) -> str:
    """A map of ``grid`` in ``folder`` with a world file holding ``settings``; its spec."""
    spec = map_spec(folder, grid)
    (folder / "map.world.yaml").write_text(yaml.safe_dump(settings))
    return spec


def no_files_under(root: Path) -> bool:
    return not root.exists() or not any(p.is_file() for p in root.rglob("*"))


# --- specs --------------------------------------------------------------------------------------------

def test_specs_name_imported_worlds_and_generated_splits(box, tmp_path, monkeypatch):
    spec, world = box
    path = Path(spec[len("map:"):])
    assert is_world_spec(spec) and is_world_spec("mesh:house.glb") and not is_world_spec("test")
    assert not is_world_spec("map") and not is_world_spec("floor:x.yaml")
    assert parse_world_spec(spec) == ("map", path)
    assert world_file_path(spec) == path.with_name("map.world.yaml")
    assert canonical_spec("train") == "train"
    monkeypatch.chdir(path.parent.parent)
    relative = f"map:{path.parent.name}/map.yaml"
    assert canonical_spec(relative) == spec and load_world(relative) is world  # one world whatever names it
    assert worlds_of(spec) == [world] and world.scene_id == "box"  # a map.yaml is named by its folder
    with pytest.raises(ConfigError, match=r"does not exist"):
        parse_world_spec(f"map:{tmp_path / 'nowhere.yaml'}")
    with pytest.raises(ConfigError, match=r"is not a world: use map:PATH/map\.yaml"):
        parse_world_spec("floor:x.yaml")


def test_a_map_file_of_another_name_names_its_world_and_world_file(tmp_path):
    path = tmp_path / "maps" / "office.yaml"
    spec = f"map:{path}"
    from m2h_ros.core.world.ros_map import write_ros_map

    write_ros_map(path, BOX)
    assert world_file_path(spec) == path.with_name("office.world.yaml")
    path.with_name("office.world.yaml").write_text("wall_height: 2.8\n")
    world = load_world(spec)
    assert world.scene_id == "office" and world.height == 2.8


# --- the world file --------------------------------------------------------------------------------

def test_no_world_file_means_every_default(box, tmp_path):
    _, world = box
    assert read_world_file(tmp_path / "none.world.yaml", kind="map") == WorldFile()
    defaults = PlanSettings()
    assert world.height == defaults.wall_height and world.grid.spacing == defaults.lattice_spacing
    assert {(r.wall_material, r.floor_material, r.ceiling_material, r.furnishing) for r in world.rooms} == \
        {(defaults.wall_material, defaults.floor_material, defaults.ceiling_material, defaults.furnishing)}


@pytest.mark.parametrize("settings", [{"wall_height": 3.2}, {"lattice_spacing": 0.5}, {"robot_radius": 0.6},
                                      {"wall_material": "brickwork", "floor_material": "carpet_thin",
                                       "ceiling_material": "wood_1.6cm"},
                                      {"furnishing": "bare"}],
                         ids=["wall_height", "lattice_spacing", "robot_radius", "materials", "furnishing"])
def test_each_setting_changes_the_world_and_its_fingerprint(box, tmp_path, settings):
    _, default = box
    world = load_world(with_world_file(tmp_path / "box", settings))
    assert world.fingerprint() != default.fingerprint()
    room = world.rooms[0]
    if "wall_height" in settings:
        assert world.height == 3.2 and max(c[2] for s in world.surfaces for c in s.corners) == 3.2
        assert (room_rt60(world, 0) > room_rt60(default, 0)).all()  # more volume, the same absorption per m^2
    if "lattice_spacing" in settings:
        assert world.grid.spacing == 0.5 and world.grid.n_nodes > 3 * default.grid.n_nodes
    if "robot_radius" in settings:
        assert 0 < world.grid.n_nodes < default.grid.n_nodes
        x, y = world.grid.positions.T
        assert (np.minimum.reduce([x, 4.0 - x, y, 3.0 - y]) >= 0.6).all()  # clear of the walls
    if "wall_material" in settings:
        assert (room.wall_material, room.floor_material, room.ceiling_material) == \
            ("brickwork", "carpet_thin", "wood_1.6cm")
        faces = {("wall" if s.outward[2] == 0 else "floor" if s.outward[2] < 0 else "ceiling", s.material)
                 for s in world.surfaces}
        assert faces == {("wall", "brickwork"), ("floor", "carpet_thin"), ("ceiling", "wood_1.6cm")}
    if "furnishing" in settings:
        assert room.furnishing == "bare" and (room_rt60(world, 0) > room_rt60(default, 0)).all()


def test_rooms_given_as_polygons_split_a_room(tmp_path):
    grid = box_grid(6.0, 3.0)
    spec = with_world_file(tmp_path / "split", {"rooms": [
        {"name": "west", "polygon": [[0, 0], [3, 0], [3, 3], [0, 3]], "wall_material": "brickwork",
         "furnishing": "bedroom"},
        {"name": "east", "polygon": [[3, 0], [6, 0], [6, 3], [3, 3]], "floor_material": "carpet_thin"}]}, grid)
    world = load_world(spec)
    assert [room.name for room in world.rooms] == ["west", "east"]
    west, east = world.rooms
    assert world.room_at((1.0, 1.5)) == 0 and world.room_at((5.0, 1.5)) == 1
    assert west.area == pytest.approx(9.0, rel=0.03) and east.area == pytest.approx(9.0, rel=0.03)
    assert (west.wall_material, west.floor_material, west.furnishing) == ("brickwork", "linoleum_on_concrete", "bedroom")
    assert (east.wall_material, east.floor_material, east.furnishing) == ("plasterboard", "carpet_thin", "living")
    assert set(world.grid.room_of.tolist()) == {0, 1} and world.grid.n_components == 1
    assert not world.doors  # a 3 m wide boundary is open plan: no wall, no lintel
    assert all(-1 in wall.rooms for wall in world.walls)


def test_rooms_given_as_a_label_image_split_a_room(tmp_path):
    grid = box_grid(6.0, 3.0)
    rows, cols = grid.cells.shape
    ys = grid.origin[1] + (np.arange(rows) + 0.5) * grid.resolution
    labels = np.where(ys[:, None] < 1.0, 1, 2) * np.ones((1, cols), np.uint8)  # row 0: the bottom
    folder = tmp_path / "labelled"
    folder.mkdir()
    Image.fromarray(np.flipud(labels).astype(np.uint8)).save(folder / "rooms.png")  # the image's top row first
    spec = with_world_file(folder, {"room_labels": "rooms.png", "rooms": [{"name": "south"}, {"name": "north"}]},
                           grid)
    world = load_world(spec)
    assert [room.name for room in world.rooms] == ["south", "north"]
    assert world.room_at((3.0, 0.5)) == 0 and world.room_at((3.0, 2.5)) == 1
    assert world.rooms[0].area == pytest.approx(6.0, rel=0.03) and world.rooms[1].area == pytest.approx(12.0, rel=0.03)
    Image.fromarray(np.zeros((rows, cols - 1), np.uint8)).save(folder / "rooms.png")
    with pytest.raises(ConfigError, match=rf"rooms\.png must be one channel of {cols} x {rows} pixels"):
        load_world(spec)


@pytest.mark.parametrize("settings, message", [
    ({"wall_heigth": 3.0}, r"unknown setting 'wall_heigth' \(did you mean 'wall_height'\?\)"),
    ({"units": "cm"}, r"unknown setting 'units'"),  # a mesh's setting, not a map's
    ({"wall_material": "plasterbord"}, r"unknown acoustic material\(s\): 'plasterbord' \(did you mean 'plasterboard'"),
    ({"rooms": [{"name": "a", "ceiling_material": "cloud"}]}, r"unknown acoustic material\(s\): 'cloud'"),
    ({"furnishing": "palace"}, r"furnishing 'palace' is unknown; choose one of"),
    ({"rooms": [{"name": "a", "furnishing": "palace"}]}, r"furnishing 'palace' is unknown"),
    ({"rooms": [{"nmae": "a"}]}, r"room 0 has unknown setting 'nmae' \(did you mean 'name'\?\)"),
    ({"rooms": [{"polygon": [[0, 0], [1, 1]]}]}, r"room 0's polygon needs at least 3"),
    ({"rooms": [{"polygon": [[0, 0], [1, 0], [1, 1]]}, {"name": "b"}]}, r"give every room a polygon, or none"),
    ({"rooms": "several"}, r"rooms must be 'auto' or a list"),
    ({"wall_height": 2.0}, r"door_height \(2.1 m\) must be below wall_height"),
    ({"lattice_spacing": 0}, r"lattice_spacing must be a positive number"),
    ({"robot_radius": 2.5}, r"robot_radius must be in \[0, 2\)"),
], ids=["key", "mesh_key", "material", "room_material", "furnishing", "room_furnishing", "room_key", "polygon",
        "some_polygons", "rooms", "door_above_ceiling", "spacing", "radius"])
def test_a_bad_world_file_is_named_with_the_fix(tmp_path, settings, message):
    spec = with_world_file(tmp_path / "bad", settings)
    with pytest.raises(ConfigError, match=rf"world file .*bad/map\.world\.yaml.*{message}"):
        load_world(spec)


# --- fingerprints and the memo ------------------------------------------------------------------------

def test_the_fingerprint_follows_the_files_not_where_they_are(box, tmp_path):
    spec, world = box
    folder = Path(spec[len("map:"):]).parent
    copy = tmp_path / "elsewhere" / "copy"
    shutil.copytree(folder, copy)
    moved = load_world(f"map:{copy / 'map.yaml'}")
    assert moved is not world and moved.fingerprint() == world.fingerprint() and moved.scene_id == "copy"
    cells = BOX.cells.copy()
    cells[30, 30] = OCCUPIED  # one pixel: a speck of noise, the same world, but another map
    changed = load_world(map_spec(tmp_path / "pixel", OccupancyGrid(cells, BOX.resolution, BOX.origin)))
    assert changed.fingerprint() != world.fingerprint()
    (copy / "map.world.yaml").write_text("door_height: 2.0\n")
    assert load_world(f"map:{copy / 'map.yaml'}").fingerprint() != world.fingerprint()


def test_load_world_memoises_until_a_file_changes(tmp_path):
    spec = map_spec(tmp_path / "memo", BOX)
    folder = tmp_path / "memo"
    first = load_world(spec)
    assert load_world(spec) is first and load_world_with_report(spec)[0] is first
    (folder / "map.world.yaml").write_text("wall_height: 2.7\n")
    second = load_world(spec)
    assert second is not first and second.height == 2.7 and load_world(spec) is second
    cells = BOX.cells.copy()
    cells[10, 10] = OCCUPIED
    edited = Path(map_spec(tmp_path / "edited", OccupancyGrid(cells, BOX.resolution, BOX.origin))[len("map:"):])
    shutil.copyfile(edited.with_suffix(".pgm"), folder / "map.pgm")  # only the image changes
    third = load_world(spec)
    assert third is not second and third.fingerprint() != second.fingerprint() and third.height == 2.7
    os.utime(folder / "map.pgm")  # touched, not changed: read again, the same world
    assert load_world(spec).fingerprint() == third.fingerprint()


# --- bad maps: named, and nothing written -------------------------------------------------------------

def test_bad_map_files_are_named_with_the_fix_and_write_no_episodes(box, folder_library, tmp_path, monkeypatch):
    data = tmp_path / "data"
    monkeypatch.setenv("M2H_DATA_DIR", str(data))
    good = Path(box[0][len("map:"):])

    def broken(name: str, edit) -> str:
        folder = tmp_path / name
        shutil.copytree(good.parent, folder)
        edit(folder)
        return f"map:{folder / 'map.yaml'}"

    def set_key(key, value):
        def edit(folder):
            document = yaml.safe_load((folder / "map.yaml").read_text())
            document[key] = value
            (folder / "map.yaml").write_text(yaml.safe_dump(document))
        return edit

    def sixteen_bits(folder):
        Image.fromarray(np.full((20, 20), 65535, np.uint16)).save(folder / "deep.png")
        set_key("image", "deep.png")(folder)

    cases = {
        "missing_image": (set_key("image", "gone.pgm"), MapError, r"missing_image/gone\.pgm: no such map image"),
        "sixteen_bits": (sixteen_bits, MapError, r"sixteen_bits/deep\.png: a 16-bit image.*save it as 8-bit grey"),
        "unknown_key": (set_key("treshold", 0.5), MapError,
                        r"unknown_key/map\.yaml: unknown key 'treshold' \(nearest known key: '[a-z_]+'\)"),
        # map_server before 1.3.7's free_thresh reads the unknown grey as free: the plan leaks off the image.
        "old_free_thresh": (set_key("free_thresh", 0.25), ConfigError,
                            r"old_free_thresh/map\.yaml: free space runs off the edge.*free_thresh: 0\.25.*0\.196"),
    }
    for name, (edit, error, message) in cases.items():
        config = EpisodeConfig(scene_split=broken(name, edit), count=4)
        with pytest.raises(error, match=message):
            load_world(config.scene_split)
        with pytest.raises(error, match=message):
            episodes_for(config, folder_library)
    assert no_files_under(data)


def test_a_world_too_small_for_the_episodes_is_refused_before_any_file(box, folder_library, tmp_path, monkeypatch):
    monkeypatch.setenv("M2H_DATA_DIR", str(tmp_path / "data"))
    spec, world = box
    config = EpisodeConfig(scene_split=spec, count=4)  # sources 8 m apart in a 4 x 3 m room
    assert world.grid.geodesic.max() < config.min_source_distance
    with pytest.raises(EpisodeError, match=r"scene box cannot hold 2 sources 8\.0 m apart.*lower min_source_distance"):
        episodes_for(config, folder_library)
    assert not episode_path(config, folder_library).exists() and no_files_under(tmp_path / "data")
    # The same room holds sources 2 m apart.
    small = EpisodeConfig(scene_split=spec, count=4, min_source_distance=2.0, near_radius=2.0)
    assert len(episodes_for(small, folder_library)) == 4 and episode_path(small, folder_library).exists()


def test_worlds_of_a_corridor_spec_is_its_one_world(tmp_path):
    spec = map_spec(tmp_path / "corridor", corridor_grid(0.8))
    worlds = worlds_of(spec)
    assert len(worlds) == 1 and worlds[0].source == "map" and len(worlds[0].rooms) == 2
