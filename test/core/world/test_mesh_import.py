"""Meshes made elsewhere: reading glTF/GLB, OBJ and PLY into metres with z up, their floor plans found by
ray casting, part names and the material map that gives imported surfaces acoustic materials.

The test house is an L of two rooms built from boxes, as a Blender or Gazebo model is: a floor slab, a
ceiling slab at 2.6 m (whose top is a flat roof), 10 cm outer walls, an inner wall with a door under a
lintel, and a table.
"""

from __future__ import annotations

import base64
import json
from dataclasses import dataclass

import numpy as np
import pytest
import trimesh
from PIL import Image
from trimesh.visual.material import PBRMaterial

from m2h_ros.core.world.frames import FREE, OCCUPIED, UNKNOWN
from m2h_ros.core.world.mesh_import import (Y_UP_TO_Z_UP, material_for, mesh_floor_plan, part_at, read_material_map,
                                            read_mesh)
from m2h_ros.core.world.raycast import RayCaster
from m2h_ros.errors import ConfigError

# Room A: x 0..6, y 0..3.95; room B: x 0..3, y 4.05..8; the wall between them at y 3.95..4.05 has a door
# at x 1.0..1.9 up to 2.0 m. The table stands in room A.
DOOR = (1.0, 1.9)
TABLE = ((4.0, 1.0, 0.0), (5.0, 2.0, 0.75))
# A wardrobe on short legs in room B: the floor runs on under it and its top is above the head room, so
# only the horizontal rays find it (from inside they meet its faces from behind).
WARDROBE = ((0.2, 6.5, 0.05), (1.0, 7.8, 2.2))
ROOMS = (((0.0, 0.0), (6.0, 3.95)), ((0.0, 4.05), (3.0, 8.0)))


@dataclass(frozen=True)
class Part:
    name: str
    material: str
    rgb: tuple[float, float, float]
    boxes: tuple[tuple[tuple[float, float, float], tuple[float, float, float]], ...]


def house_parts(*, z0: float = 0.0, upper: bool = False) -> list[Part]:
    """The L-shaped house standing at ``z0``; ``upper``: only room A (a storey on top of the house)."""
    def shift(box):
        (x0, y0, a), (x1, y1, b) = box
        return (x0, y0, a + z0), (x1, y1, b + z0)

    slabs = [((-0.1, -0.1), (6.1, 4.05))] + ([] if upper else [((-0.1, 4.05), (3.1, 8.1))])
    walls = [((-0.1, -0.1, 0), (6.1, 0.0, 2.6)),  # south
             ((6.0, 0.0, 0), (6.1, 4.05, 2.6)),  # east of A
             ((3.0, 3.95, 0), (6.0, 4.05, 2.6)),  # north of A, beside B
             ((-0.1, 0.0, 0), (0.0, 4.05 if upper else 8.1, 2.6))]  # west
    if upper:
        walls.append(((0.0, 3.95, 0), (3.0, 4.05, 2.6)))
    else:
        walls += [((0.0, 3.95, 0), (DOOR[0], 4.05, 2.6)), ((DOOR[1], 3.95, 0), (3.0, 4.05, 2.6)),  # inner wall
                  ((DOOR[0], 3.95, 2.0), (DOOR[1], 4.05, 2.6)),  # lintel over the door
                  ((3.0, 4.05, 0), (3.1, 8.1, 2.6)), ((-0.1, 8.0, 0), (3.1, 8.1, 2.6))]  # east and north of B
    parts = [Part("Floor", "tile", (0.8, 0.8, 0.7), tuple(((x0, y0, -0.1), (x1, y1, 0.0)) for (x0, y0), (x1, y1) in slabs)),
             Part("Ceiling", "plaster", (1.0, 1.0, 1.0),
                  tuple(((x0, y0, 2.6), (x1, y1, 2.7)) for (x0, y0), (x1, y1) in slabs)),
             Part("Walls", "brick", (0.0, 0.0, 1.0), tuple(walls))]
    if not upper:
        parts += [Part("Table", "oak", (1.0, 0.0, 0.0), (TABLE,)), Part("Wardrobe", "oak", (1.0, 0.0, 0.0), (WARDROBE,))]
    return [Part(p.name, p.material, p.rgb, tuple(shift(b) for b in p.boxes)) for p in parts]


def part_mesh(part: Part) -> trimesh.Trimesh:
    boxes = [trimesh.creation.box(extents=np.subtract(hi, lo),
                                  transform=trimesh.transformations.translation_matrix(np.add(lo, hi) / 2))
             for lo, hi in part.boxes]
    return trimesh.util.concatenate(boxes)


def write_glb(parts: list[Part], path, *, transform=np.eye(4), vertex_colored=("Walls",)) -> None:
    """A glTF scene, one node per part: vertex colours for ``vertex_colored``, base colours for the rest."""
    scene = trimesh.Scene()
    for part in parts:
        mesh = part_mesh(part)
        if part.name in vertex_colored:
            mesh.visual = trimesh.visual.ColorVisuals(mesh, vertex_colors=np.round(np.array(part.rgb) * 255).astype(np.uint8))
        else:
            mesh.visual = trimesh.visual.TextureVisuals(material=PBRMaterial(
                name=part.material, baseColorFactor=np.round(np.array([*part.rgb, 1.0]) * 255).astype(np.uint8)))
        scene.add_geometry(mesh, node_name=part.name, geom_name=f"{part.name}Mesh", transform=transform)
    scene.export(path)


def write_obj(parts: list[Part], path, *, scale: float = 1.0) -> None:
    """An OBJ file with one group and material per part and its MTL file beside it."""
    lines, materials, offset = [f"mtllib {path.stem}.mtl"], [], 1
    for part in parts:
        mesh = part_mesh(part)
        lines += [f"g {part.name}", f"usemtl {part.material}"]
        lines += [f"v {x:.6f} {y:.6f} {z:.6f}" for x, y, z in mesh.vertices * scale]
        lines += [f"f {a} {b} {c}" for a, b, c in mesh.faces + offset]
        offset += len(mesh.vertices)
        materials += [f"newmtl {part.material}", "Kd {:.4f} {:.4f} {:.4f}".format(*part.rgb)]
    path.write_text("\n".join(lines) + "\n")
    path.with_suffix(".mtl").write_text("\n".join(materials) + "\n")


def write_ply(parts: list[Part], path, *, scale: float = 1.0) -> None:
    """One PLY mesh with each part's colour on its vertices."""
    meshes = []
    for part in parts:
        mesh = part_mesh(part)
        mesh.visual = trimesh.visual.ColorVisuals(mesh, vertex_colors=np.round(np.array(part.rgb) * 255).astype(np.uint8))
        meshes.append(mesh)
    house = trimesh.util.concatenate(meshes)
    house.apply_scale(scale)
    house.export(path)


def y_up() -> np.ndarray:
    """The transform that lays the z-up house into glTF's y-up frame."""
    transform = np.eye(4)
    transform[:3, :3] = Y_UP_TO_Z_UP.T
    return transform


@pytest.fixture(scope="module")
def house_files(tmp_path_factory):
    folder = tmp_path_factory.mktemp("house")
    parts = house_parts()
    write_glb(parts, folder / "house.glb", transform=y_up())
    write_obj(parts, folder / "house.obj")
    write_ply(parts, folder / "house.ply")
    return folder


@pytest.fixture(scope="module")
def house(house_files):
    return read_mesh(house_files / "house.glb")


def cell_value(plan, x, y):
    ix, iy = plan.grid.cell_of((x, y))
    return plan.grid.cells[iy, ix]


def cells_where(plan, value) -> np.ndarray:
    """(N, 2) centres of the plan's cells holding ``value``."""
    iy, ix = np.nonzero(plan.grid.cells == value)
    return plan.grid.cell_centres(ix, iy)


def inside(xy: np.ndarray, lo, hi, *, by: float = 0.0) -> np.ndarray:
    return np.all((xy > np.add(lo[:2], by)) & (xy < np.subtract(hi[:2], by)), axis=1)


# ----------------------------------------------------------------------------- reading


@pytest.mark.parametrize("name", ["house.glb", "house.obj", "house.ply"])
def test_each_format_reads_back_in_metres_with_z_up(house_files, name):
    mesh = read_mesh(house_files / name)
    np.testing.assert_allclose(mesh.bounds, [[-0.1, -0.1, -0.1], [6.1, 8.1, 2.7]], atol=1e-5)
    assert mesh.n_faces == sum(12 * len(part.boxes) for part in house_parts())
    # Floors face up: the highest upward-facing triangle below 1 m is the table top.
    tops = mesh.triangles[mesh.normals[:, 2] > 0.9][:, :, 2].mean(axis=1)
    assert tops[tops < 1.0].max() == pytest.approx(0.75, abs=1e-5)


def test_a_y_up_gltf_read_as_z_up_stands_on_its_side(house_files):
    sideways = read_mesh(house_files / "house.glb", up_axis="z")
    np.testing.assert_allclose(sideways.bounds, [[-0.1, -0.1, -8.1], [6.1, 2.7, 0.1]], atol=1e-5)  # glTF z is -y


def test_units_scale_to_metres_and_a_mesh_in_millimetres_is_recognised(tmp_path, house_files):
    path = tmp_path / "house_mm.ply"
    write_ply(house_parts(), path, scale=1000.0)
    mesh = read_mesh(path, units="mm")
    np.testing.assert_allclose(mesh.bounds, [[-0.1, -0.1, -0.1], [6.1, 8.1, 2.7]], atol=1e-4)
    np.testing.assert_allclose(read_mesh(path, units=0.001).vertices, mesh.vertices)
    with pytest.raises(ConfigError, match="house_mm.ply.*looks like millimetres: pass units=mm"):
        read_mesh(path)
    centimetres = tmp_path / "house_cm.obj"
    write_obj(house_parts(), centimetres, scale=100.0)
    with pytest.raises(ConfigError, match="looks like centimetres: pass units=cm"):
        read_mesh(centimetres)
    assert read_mesh(centimetres, units="cm").bounds[1, 1] == pytest.approx(8.1)
    with pytest.raises(ConfigError, match=r"is 0.0082 m across with units='mm'; it looks like metres: pass units=m "
                                          r"\(8.2 m across"):
        read_mesh(house_files / "house.ply", units="mm")
    with pytest.raises(ConfigError, match=r"is 8.2e-06 m across with units=0.001, too small for a building"):
        write_ply(house_parts(), tmp_path / "tiny.ply", scale=0.001)
        read_mesh(tmp_path / "tiny.ply", units=0.001)


def test_bad_options_and_files_are_named_in_the_error(tmp_path, house_files):
    with pytest.raises(ConfigError, match="nowhere.glb does not exist"):
        read_mesh(tmp_path / "nowhere.glb")
    (tmp_path / "house.fbx").write_bytes(b"Kaydara FBX Binary")
    with pytest.raises(ConfigError, match=r"house.fbx: cannot read '.fbx' meshes; export it as one of .glb"):
        read_mesh(tmp_path / "house.fbx")
    with pytest.raises(ConfigError, match="units='furlong' must be one of mm, cm, m, in, ft"):
        read_mesh(house_files / "house.ply", units="furlong")
    with pytest.raises(ConfigError, match="up_axis='x' must be 'y' or 'z'"):
        read_mesh(house_files / "house.ply", up_axis="x")
    truncated = tmp_path / "truncated.glb"
    truncated.write_bytes((house_files / "house.glb").read_bytes()[:200])
    garbage = tmp_path / "garbage.ply"
    garbage.write_bytes(b"ply\nformat binary_little_endian 1.0\nelement vertex 99\n" + bytes(range(256)) * 4)
    for corrupt in (truncated, garbage):
        with pytest.raises(ConfigError, match=f"cannot read .*{corrupt.name} as a (GLB|PLY) mesh"):
            read_mesh(corrupt)
    points = tmp_path / "points.obj"
    points.write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\n")
    with pytest.raises(ConfigError, match="points.obj holds no triangles"):
        read_mesh(points)


def test_parts_come_from_gltf_nodes_and_obj_groups_with_their_materials(house, house_files):
    assert set(house.parts) == {"Floor/tile", "Ceiling/plaster", "Walls", "Table/oak", "Wardrobe/oak"}
    assert set(read_mesh(house_files / "house.obj").parts) == {"Floor/tile", "Ceiling/plaster", "Walls/brick",
                                                             "Table/oak", "Wardrobe/oak"}
    assert read_mesh(house_files / "house.ply").parts == ("house.ply",)
    table = house.face_part == house.parts.index("Table/oak")
    assert table.sum() == 12 and house.bounds[1, 2] > house.vertices[np.unique(house.faces[table])][:, 2].max()


@pytest.mark.parametrize("name", ["house.glb", "house.obj", "house.ply"])
def test_face_colours_come_from_vertex_colours_and_material_base_colours(house_files, name):
    mesh = read_mesh(house_files / name)
    corners = mesh.vertices[mesh.faces]
    table = np.all((corners > [3.99, 0.99, -0.01]) & (corners < [5.01, 2.01, 0.76]), axis=(1, 2))
    wall = np.all((corners[:, :, 2] > -0.01) & (corners[:, :, 2] < 2.61) & (corners[:, :, 1] < 0.01), axis=1)
    assert table.sum() == 12 and wall.sum() >= 12
    np.testing.assert_allclose(mesh.face_colors[table], np.tile([1.0, 0.0, 0.0], (table.sum(), 1)), atol=1e-6)
    np.testing.assert_allclose(mesh.face_colors[wall], np.tile([0.0, 0.0, 1.0], (wall.sum(), 1)), atol=1e-6)


def test_gltf_colours_are_linear_and_come_out_as_display_srgb(tmp_path):
    box = trimesh.creation.box()
    # 0.2140 linear is 0.5 on the display; a 55 % grey texel times a 0.5 factor is 0.402 on the display.
    box.visual = trimesh.visual.TextureVisuals(material=PBRMaterial(baseColorFactor=[0.2140, 0.2140, 0.2140, 1.0]))
    textured = trimesh.creation.box()
    uv = np.zeros((len(textured.vertices), 2))
    uv[:, 0] = textured.vertices[:, 0] > 0  # the +x half of the box samples the texture's right half
    image = Image.new("RGB", (2, 1))
    image.putpixel((0, 0), (255, 0, 0))
    image.putpixel((1, 0), (140, 140, 140))
    textured.visual = trimesh.visual.TextureVisuals(uv=uv, material=PBRMaterial(
        baseColorTexture=image, baseColorFactor=[0.5, 0.5, 0.5, 1.0]))
    scene = trimesh.Scene()
    scene.add_geometry(box, node_name="plain")
    scene.add_geometry(textured, node_name="textured", transform=trimesh.transformations.translation_matrix([2, 0, 0]))
    scene.export(tmp_path / "colours.glb")
    mesh = read_mesh(tmp_path / "colours.glb", units=4.0)  # 12 m across: a room's size
    plain = mesh.face_part == next(i for i, name in enumerate(mesh.parts) if name.startswith("plain"))
    np.testing.assert_allclose(mesh.face_colors[plain], 0.5, atol=0.01)
    right = ~plain & (mesh.vertices[mesh.faces][:, :, 0].min(axis=1) > 8.0 + 1e-6)
    left = ~plain & (mesh.vertices[mesh.faces][:, :, 0].max(axis=1) < 8.0 - 1e-6)
    assert right.sum() == 2 and left.sum() == 2
    np.testing.assert_allclose(mesh.face_colors[right], 0.402, atol=0.01)
    np.testing.assert_allclose(mesh.face_colors[left], np.tile([0.735, 0.0, 0.0], (2, 1)), atol=0.01)


def test_a_gltf_mesh_of_several_primitives_is_one_part_per_material_and_vertex_paint_tints_its_material(tmp_path):
    """A glTF node "Room" whose mesh has two primitives (as scans and Blender exports have: one per material),
    one of them vertex-painted, and an unnamed node beside it."""
    positions = np.array([[0, 0, 0], [4, 0, 0], [0, 0, -4], [0, 1, 0], [4, 1, 0], [0, 1, -4]], np.float32)
    paint = np.array([[1.0, 0.0, 0.0, 1.0]] * 3 + [[0.0, 1.0, 0.0, 1.0]] * 3, np.float32)
    first, second = np.array([0, 1, 2], np.uint16), np.array([3, 4, 5], np.uint16)
    blob = positions.tobytes() + paint.tobytes() + first.tobytes() + second.tobytes()
    views = [(0, 72), (72, 96), (168, 6), (174, 6)]
    document = {
        "asset": {"version": "2.0"}, "scene": 0, "scenes": [{"nodes": [0, 1]}],
        "nodes": [{"name": "Room", "mesh": 0}, {"mesh": 1, "translation": [5, 0, 0]}],
        "meshes": [{"name": "RoomMesh", "primitives": [
            {"attributes": {"POSITION": 0}, "indices": 2, "material": 0},
            {"attributes": {"POSITION": 0, "COLOR_0": 1}, "indices": 3, "material": 1}]},
            {"primitives": [{"attributes": {"POSITION": 0}, "indices": 2}]}],
        "materials": [{"name": "Brick", "pbrMetallicRoughness": {"baseColorFactor": [0.2140, 0.2140, 0.2140, 1]}},
                      {"name": "Paint", "pbrMetallicRoughness": {"baseColorFactor": [0.5, 0.5, 0.5, 1]}}],
        "buffers": [{"byteLength": len(blob),
                     "uri": "data:application/octet-stream;base64," + base64.b64encode(blob).decode()}],
        "bufferViews": [{"buffer": 0, "byteOffset": offset, "byteLength": length} for offset, length in views],
        "accessors": [{"bufferView": 0, "componentType": 5126, "count": 6, "type": "VEC3",
                       "min": [0, 0, -4], "max": [4, 1, 0]},
                      {"bufferView": 1, "componentType": 5126, "count": 6, "type": "VEC4"},
                      {"bufferView": 2, "componentType": 5123, "count": 3, "type": "SCALAR"},
                      {"bufferView": 3, "componentType": 5123, "count": 3, "type": "SCALAR"}]}
    (tmp_path / "room.gltf").write_text(json.dumps(document))
    mesh = read_mesh(tmp_path / "room.gltf")
    assert sorted(mesh.parts) == ["1", "Room/Brick", "Room/Paint"]
    brick, paint_part = mesh.parts.index("Room/Brick"), mesh.parts.index("Room/Paint")
    np.testing.assert_allclose(mesh.face_colors[mesh.face_part == brick], [[0.5, 0.5, 0.5]], atol=0.01)
    # The painted triangle's corners are green: a 0.5 linear base colour times green paint, 0.735 displayed.
    np.testing.assert_allclose(mesh.face_colors[mesh.face_part == paint_part], [[0.0, 0.735, 0.0]], atol=0.01)
    np.testing.assert_allclose(mesh.face_colors[mesh.face_part == mesh.parts.index("1")], [[0.5, 0.5, 0.5]])
    np.testing.assert_allclose(mesh.bounds, [[0, 0, 0], [9, 4, 1]], atol=1e-6)  # y-up: glTF -z is +y


# ----------------------------------------------------------------------------- floor plan


@pytest.mark.parametrize("name", ["house.glb", "house.obj", "house.ply"])
def test_the_floor_plan_frees_the_rooms_and_blocks_walls_and_the_table(house_files, name):
    plan = mesh_floor_plan(read_mesh(house_files / name), resolution=0.05)
    assert plan.grid.origin == pytest.approx((-0.15, -0.15)) and plan.grid.yaw == 0.0
    assert plan.floor_z == pytest.approx(0.0, abs=1e-4) and plan.ceiling_z == pytest.approx(2.6, abs=1e-4)
    free, occupied = cells_where(plan, FREE), cells_where(plan, OCCUPIED)
    # Every free cell lies in a room or the door; none in a wall or under the table.
    in_rooms = inside(free, *ROOMS[0]) | inside(free, *ROOMS[1])
    in_door = inside(free, (DOOR[0], 3.9), (DOOR[1], 4.1))
    assert np.all(in_rooms | in_door)
    assert not np.any(inside(free, *TABLE)) and not np.any(inside(free, *WARDROBE))
    # Every cell well inside a room is free except around the furniture; the door is free.
    for lo, hi in ROOMS:
        xs, ys = np.meshgrid(np.arange(lo[0] + 0.08, hi[0] - 0.08, 0.05), np.arange(lo[1] + 0.08, hi[1] - 0.08, 0.05))
        points = np.column_stack([xs.ravel(), ys.ravel()])
        for lo, hi in (TABLE, WARDROBE):
            points = points[~inside(points, np.subtract(lo, 0.08), np.add(hi, 0.08))]
        ix, iy = plan.grid.cell_of(points)
        assert np.all(plan.grid.cells[iy, ix] == FREE)
    for x in np.arange(DOOR[0] + 0.08, DOOR[1] - 0.08, 0.05):
        assert cell_value(plan, x, 4.0) == FREE
    expected = 6 * 3.95 + 3 * 3.95 - 1.0 - 0.8 * 1.3  # rooms minus the table and the wardrobe, m^2
    assert len(free) * 0.05**2 == pytest.approx(expected, rel=0.04)
    # The walls are drawn whole: occupied cells line every wall, the inner one and the table.
    assert cell_value(plan, 3.0, -0.05) == OCCUPIED and cell_value(plan, 6.05, 2.0) == OCCUPIED
    assert cell_value(plan, 0.5, 4.0) == OCCUPIED and cell_value(plan, 2.5, 4.0) == OCCUPIED
    assert cell_value(plan, 4.5, 1.5) == OCCUPIED and cell_value(plan, 4.02, 1.02) == OCCUPIED
    assert cell_value(plan, 0.6, 7.0) == OCCUPIED
    assert len(occupied) > 0.9 * (2 * (6.2 + 8.2) + 3.0) / 0.05
    # Beyond the L and the margin of the grid is unknown.
    assert cell_value(plan, 5.0, 6.0) == UNKNOWN and cell_value(plan, 6.13, 0.5) == UNKNOWN
    margin = np.concatenate([plan.grid.cells[[0, -1]].ravel(), plan.grid.cells[:, [0, -1]].ravel()])
    assert np.mean(margin == UNKNOWN) > 0.98 and not np.any(margin == FREE)


def test_the_flat_roof_is_a_level_but_the_floor_under_the_ceiling_is_planned(house):
    plan = mesh_floor_plan(house, resolution=0.1)
    assert [round(level.z, 3) for level in plan.levels] == [0.0, 2.7]
    floor, roof = plan.levels
    assert plan.level == 0 and floor.roofed_area == pytest.approx(floor.area) and roof.roofed_area == 0.0
    assert roof.area > floor.area  # nothing stands on the roof, so the largest area alone would pick it
    on_roof = mesh_floor_plan(house, resolution=0.1, floor_level=1)
    assert on_roof.floor_z == pytest.approx(2.7) and on_roof.ceiling_z is None
    assert cell_value(on_roof, 4.5, 1.5) == FREE and cell_value(on_roof, 5.0, 6.0) == UNKNOWN


def quad(corners, facing) -> trimesh.Trimesh:
    """Two triangles over four corners (in order around the quad) whose normal points along ``facing``."""
    corners = np.asarray(corners, float)
    faces = np.array([[0, 1, 2], [0, 2, 3]])
    if np.dot(np.cross(corners[1] - corners[0], corners[2] - corners[0]), facing) < 0:
        faces = faces[:, ::-1]
    return trimesh.Trimesh(corners, faces, process=False)


def wall(x0, y0, x1, y1, z0, z1, facing) -> trimesh.Trimesh:
    return quad([(x0, y0, z0), (x1, y1, z0), (x1, y1, z1), (x0, y0, z1)], facing)


def scanned_house() -> trimesh.Trimesh:
    """The house as a scan sees it: only the surfaces visible from inside the rooms, each facing the room
    (no floor under the walls, no outside, nothing inside the walls), and the table as an open box."""
    surfaces = []
    for (x0, y0), (x1, y1) in ROOMS:
        surfaces.append(quad([(x0, y0, 0), (x1, y0, 0), (x1, y1, 0), (x0, y1, 0)], (0, 0, 1)))
        surfaces.append(quad([(x0, y0, 2.6), (x1, y0, 2.6), (x1, y1, 2.6), (x0, y1, 2.6)], (0, 0, -1)))
        surfaces += [wall(x0, y0, x1, y0, 0, 2.6, (0, 1, 0)), wall(x0, y0, x0, y1, 0, 2.6, (1, 0, 0)),
                     wall(x1, y0, x1, y1, 0, 2.6, (-1, 0, 0))]
    (d0, d1), (a, b) = DOOR, (3.95, 4.05)
    surfaces += [wall(0, a, d0, a, 0, 2.6, (0, -1, 0)), wall(d1, a, 6, a, 0, 2.6, (0, -1, 0)),  # A's north side
                 wall(d0, a, d1, a, 2.0, 2.6, (0, -1, 0)),
                 wall(0, b, d0, b, 0, 2.6, (0, 1, 0)), wall(d1, b, 3, b, 0, 2.6, (0, 1, 0)),  # B's south side
                 wall(d0, b, d1, b, 2.0, 2.6, (0, 1, 0)),
                 wall(0, 8, 3, 8, 0, 2.6, (0, -1, 0)),  # B's north wall
                 quad([(d0, a, 0), (d1, a, 0), (d1, b, 0), (d0, b, 0)], (0, 0, 1)),  # the door: its floor,
                 wall(d0, a, d0, b, 0, 2.0, (1, 0, 0)), wall(d1, a, d1, b, 0, 2.0, (-1, 0, 0)),  # jambs and head
                 quad([(d0, a, 2.0), (d1, a, 2.0), (d1, b, 2.0), (d0, b, 2.0)], (0, 0, -1))]
    (tx0, ty0, _), (tx1, ty1, top) = TABLE
    surfaces += [quad([(tx0, ty0, top), (tx1, ty0, top), (tx1, ty1, top), (tx0, ty1, top)], (0, 0, 1)),
                 wall(tx0, ty0, tx1, ty0, 0, top, (0, -1, 0)), wall(tx0, ty1, tx1, ty1, 0, top, (0, 1, 0)),
                 wall(tx0, ty0, tx0, ty1, 0, top, (-1, 0, 0)), wall(tx1, ty0, tx1, ty1, 0, top, (1, 0, 0))]
    return trimesh.util.concatenate(surfaces)


def test_a_scans_open_surfaces_give_the_same_rooms(tmp_path):
    scanned_house().export(tmp_path / "scan.ply")
    plan = mesh_floor_plan(read_mesh(tmp_path / "scan.ply"), resolution=0.05)
    assert [level.z for level in plan.levels] == [0.0] and plan.ceiling_z == pytest.approx(2.6, abs=1e-4)
    free = cells_where(plan, FREE)
    assert np.all(inside(free, *ROOMS[0]) | inside(free, *ROOMS[1]) | inside(free, (DOOR[0], 3.9), (DOOR[1], 4.1)))
    assert not np.any(inside(free, *TABLE))
    assert len(free) * 0.05**2 == pytest.approx(6 * 3.95 + 3 * 3.95 - 1.0, rel=0.04)
    for x in np.arange(DOOR[0] + 0.08, DOOR[1] - 0.08, 0.05):
        assert cell_value(plan, x, 4.0) == FREE
    # Both faces of the inner wall occupy their cells; outside the scan is unknown.
    assert cell_value(plan, 0.5, 3.97) == OCCUPIED and cell_value(plan, 0.5, 4.03) == OCCUPIED
    assert cell_value(plan, 4.5, 1.5) == OCCUPIED and cell_value(plan, 5.0, 6.0) == UNKNOWN


def test_two_storeys_give_two_levels_and_floor_level_picks_one(tmp_path):
    parts = house_parts() + [Part(f"Upper{p.name}", p.material, p.rgb, p.boxes)
                             for p in house_parts(z0=2.7, upper=True)]
    # A bed upstairs in room A.
    parts.append(Part("Bed", "linen", (0.5, 0.5, 0.5), (((1.0, 1.0, 2.7), (3.0, 2.5, 3.2)),)))
    write_glb(parts, tmp_path / "two.glb", transform=y_up())
    mesh = read_mesh(tmp_path / "two.glb")
    plan = mesh_floor_plan(mesh, resolution=0.1)
    assert [round(level.z, 3) for level in plan.levels] == [0.0, 2.7, 5.4]  # ground, upper storey, its roof
    assert plan.level == 0 and plan.floor_z == pytest.approx(0.0, abs=1e-4)
    assert cell_value(plan, 2.0, 1.5) == FREE and cell_value(plan, 4.5, 1.5) == OCCUPIED
    upstairs = mesh_floor_plan(mesh, resolution=0.1, floor_level=1)
    assert upstairs.floor_z == pytest.approx(2.7) and upstairs.ceiling_z == pytest.approx(5.3)
    assert cell_value(upstairs, 2.0, 1.5) == OCCUPIED and cell_value(upstairs, 4.5, 1.5) == FREE
    assert cell_value(upstairs, 1.5, 4.0) == OCCUPIED  # no door upstairs
    with pytest.raises(ConfigError, match=r"floor_level=3 is not a level.*3 level\(s\).*0: z=0.00 m.*2: z=5.40 m"):
        mesh_floor_plan(mesh, resolution=0.1, floor_level=3)


def test_a_mesh_without_a_floor_is_refused(tmp_path):
    wall = trimesh.creation.box(extents=(4.0, 0.1, 2.6))
    wall.export(tmp_path / "wall.ply")
    with pytest.raises(ConfigError, match="no floor found in a mesh of 4 x 0.1 x 2.6 m"):
        mesh_floor_plan(read_mesh(tmp_path / "wall.ply"))


def test_plan_options_are_checked(house):
    with pytest.raises(ConfigError, match="resolution=0 must be in"):
        mesh_floor_plan(house, resolution=0)
    with pytest.raises(ConfigError, match="0 < step_height < head_room"):
        mesh_floor_plan(house, step_height=2.0, head_room=1.8)
    with pytest.raises(ConfigError, match="caster was built on another mesh"):
        mesh_floor_plan(house, caster=RayCaster(read_mesh_box()))


def read_mesh_box():
    from m2h_ros.core.world.raycast import TriangleMesh

    box = trimesh.creation.box()
    return TriangleMesh(box.vertices, box.faces, np.full((12, 3), 0.5))


# ----------------------------------------------------------------------------- parts and materials


def test_part_at_names_the_part_each_ray_hits(house):
    caster = RayCaster(house)
    names = part_at(house, caster, (2.0, 1.5, 0.5), [(0, -1, 0), (0, 0, 1), (0, 0, -1), (1, 0, 0)])
    assert names == ["Walls", "Ceiling/plaster", "Floor/tile", "Table/oak"]
    assert part_at(house, caster, [(2.0, 2.0, 10.0), (2.0, 2.0, 10.0)], [(0, 0, 1), (0, 0, -1)]) == [None, "Ceiling/plaster"]


def test_the_material_map_gives_parts_acoustic_materials_by_pattern(tmp_path, house):
    path = tmp_path / "materials.yaml"
    path.write_text('"Walls": brickwork\n"*/TILE": linoleum_on_concrete\n"*/oak": wood_16mm\n"*": plasterboard\n')
    mapping = read_material_map(path)
    found = {part: material_for(part, mapping, "hard_surface") for part in house.parts}
    assert found == {"Walls": "brickwork", "Floor/tile": "linoleum_on_concrete", "Table/oak": "wood_16mm",
                     "Wardrobe/oak": "wood_16mm", "Ceiling/plaster": "plasterboard"}
    assert material_for(None, mapping, "hard_surface") == "hard_surface"
    assert material_for("Door", {"Wall*": "brickwork"}, "hard_surface") == "hard_surface"


def test_a_material_map_with_unknown_materials_or_the_wrong_shape_is_refused(tmp_path):
    path = tmp_path / "materials.yaml"
    path.write_text('"Wall*": brikwork\n"Floor": carpet_thin\n"Sofa": velvet_sofa_9000\n')
    with pytest.raises(ConfigError, match=r"materials.yaml names unknown acoustic material\(s\): 'brikwork' "
                                          r"\(did you mean 'brickwork'\?\); 'velvet_sofa_9000'"):
        read_material_map(path)
    path.write_text("- brickwork\n- plasterboard\n")
    with pytest.raises(ConfigError, match="must map part names"):
        read_material_map(path)
    path.write_text("Wall: [unclosed\n")
    with pytest.raises(ConfigError, match="cannot read material map"):
        read_material_map(path)
    with pytest.raises(ConfigError, match="material map .*absent.yaml does not exist"):
        read_material_map(tmp_path / "absent.yaml")
