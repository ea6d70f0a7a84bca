"""The robot's frames, its twist between observations and the floor plan as an occupancy grid."""

import math

import numpy as np
import pytest
from rotations import rotation_matrix

from m2h_ros.core.world.frames import (FREE, OCCUPIED, UNKNOWN, base_transform, occupancy_grid, quaternion_yaw,
                                       static_transforms, twist)
from m2h_ros.core.world.scene import generate_scene


def test_the_static_frames_chain_map_to_the_camera_optical_frame():
    static = {t.child: t for t in static_transforms(head_height=1.5, eye_height=1.6)}
    assert (static["odom"].parent, static["head"].parent, static["camera"].parent) == ("map", "base_link", "head")
    assert static["head"].translation == (0.0, 0.0, 1.5) and static["camera"].translation[2] == pytest.approx(0.1)
    # The optical frame looks along the body's x with its own x to the body's right (-y), y down (-z).
    rotation = rotation_matrix(*static["camera"].rotation)
    np.testing.assert_allclose(rotation @ [0, 0, 1], [1, 0, 0], atol=1e-12)  # optical z = forward
    np.testing.assert_allclose(rotation @ [1, 0, 0], [0, -1, 0], atol=1e-12)  # optical x = right
    np.testing.assert_allclose(rotation @ [0, 1, 0], [0, 0, -1], atol=1e-12)  # optical y = down
    moved = base_transform((2.0, 3.0, math.pi / 2))
    assert (moved.parent, moved.child, moved.translation) == ("odom", "base_link", (2.0, 3.0, 0.0))
    assert quaternion_yaw(*moved.rotation) == pytest.approx(math.pi / 2)


@pytest.mark.parametrize("previous, pose, seconds, expected", [
    ((0, 0, math.pi / 2), (0, 1, math.pi / 2), 0.5, (2.0, 0.0, 0.0)),  # 1 m forward facing +y in 0.5 s
    ((1, 1, 0.0), (1, 1, math.pi / 2), 0.25, (0.0, 0.0, 2 * math.pi)),  # a left quarter turn
    ((1, 1, 0.0), (1, 1, 3 * math.pi / 2), 1.0, (0.0, 0.0, -math.pi / 2)),  # a right one, the short way round
    ((1, 1, 0.0), (3, 1, 0.0), 0.0, (0.0, 0.0, 0.0)),  # no time: no velocity
])
def test_twist_is_the_motion_in_the_robots_own_frame(previous, pose, seconds, expected):
    assert twist(previous, pose, seconds) == pytest.approx(expected)


def test_the_occupancy_grid_shows_rooms_walls_doors_and_furniture():
    scene = generate_scene(3)
    grid = occupancy_grid(scene, resolution=0.1)
    rows, cols = grid.cells.shape
    assert (cols, rows) == (scene.size[0] * 10 + 2, scene.size[1] * 10 + 2) and grid.origin == (-0.1, -0.1)

    def cell(x, y):
        return grid.cells[int((y - grid.origin[1]) / 0.1), int((x - grid.origin[0]) / 0.1)]

    for x, y in scene.grid.positions:  # every navigation node stands on free floor
        assert cell(x, y) == FREE
    for wall in scene.walls:
        middle = (np.add(wall.p0, wall.p1) / 2) + 0.01
        assert cell(*middle) == (FREE if wall.is_lintel else OCCUPIED), wall
    assert scene.doors and scene.obstacles
    for ob in scene.obstacles:
        assert cell((ob.xmin + ob.xmax) / 2, (ob.ymin + ob.ymax) / 2) == OCCUPIED
    outside = [(ix + 0.5, iy + 0.5) for ix in range(scene.size[0]) for iy in range(scene.size[1])
               if scene.cell_room[ix, iy] < 0]
    assert all(cell(x, y) in (UNKNOWN, OCCUPIED) for x, y in outside)
