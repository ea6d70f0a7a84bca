"""Camera: depth against known geometry, door gaps and lintels, colours, config, view cache."""


import numpy as np
import pytest

from m2h_ros.core.world.camera import CameraConfig, CameraViews, SceneRenderer
from m2h_ros.core.world.scene import Obstacle, build_scene, generate_scene
from m2h_ros.errors import ConfigError

CFG = CameraConfig()


def _two_rooms():
    """6 x 4 m, room 0 at x < 3, room 1 at x > 3, a door in x = 3 for 1 <= y <= 2."""
    labels = np.zeros((6, 4), dtype=int)
    labels[3:] = 1
    return build_scene(labels, doors=[((2, 1), (3, 1))])


def _row_slope(v: int, cfg: CameraConfig = CFG) -> float:
    return (cfg.height / 2 - (v + 0.5)) / cfg.focal


def test_depth_of_a_facing_wall_and_the_floor():
    scene = build_scene(np.zeros((6, 4), dtype=int))
    rgb, depth = SceneRenderer(scene).render((1.5, 2.5), 0.0)   # facing +x, wall at x = 6
    assert rgb.shape == (128, 128, 3) and rgb.dtype == np.uint8
    assert depth.shape == (128, 128) and depth.dtype == np.float32
    centre = slice(62, 66)
    np.testing.assert_allclose(depth[centre, centre], 4.5, atol=0.01)
    # Bottom row sees the floor: eye height / tan(angle below the axis).
    for v in (127, 120, 100):
        expected = CFG.eye_height / -_row_slope(v)
        np.testing.assert_allclose(depth[v, 64], expected, rtol=1e-4)
    # Top row sees the ceiling 1.2 m above the eye.
    np.testing.assert_allclose(depth[0, 64], (scene.height - CFG.eye_height) / _row_slope(0), rtol=1e-4)
    # A plane perpendicular to the axis has constant z-buffer depth across columns where visible.
    np.testing.assert_allclose(depth[64, 44:98], 4.5, atol=0.01)   # side walls elsewhere
    assert depth[64, 30] < 4.0
    # Facing -y from y = 2.5 the wall is 2.5 m away.
    _, depth_south = SceneRenderer(scene).render((1.5, 2.5), -np.pi / 2)
    np.testing.assert_allclose(depth_south[64, 64], 2.5, atol=0.01)


def test_door_gap_sees_the_next_room_under_the_lintel():
    scene = _two_rooms()
    renderer = SceneRenderer(scene)
    _, depth = renderer.render((0.5, 1.5), 0.0)   # looking through the door centre
    # Horizon rows: through the gap to the far wall of room 1 at x = 6.
    np.testing.assert_allclose(depth[64, 63:65], 5.5, atol=0.01)
    # Rows whose line of sight at x = 3 is above the door height hit the lintel, 2.5 m away.
    heights_at_wall = CFG.eye_height + np.array([_row_slope(v) for v in range(128)]) * 2.5
    lintel_rows = np.nonzero((heights_at_wall > scene.door_height + 0.02)
                             & (heights_at_wall < scene.height - 0.02))[0]
    assert len(lintel_rows) > 3
    np.testing.assert_allclose(depth[lintel_rows, 64], 2.5, atol=0.01)
    # Beside the door (the ray crosses x = 3 at y > 2.1) the wall is at 2.5 m; the gap is farther.
    _, depth_side = renderer.render((0.5, 3.5), 0.0)
    np.testing.assert_allclose(depth_side[64, 64], 2.5, atol=0.01)
    assert depth[64, 64] > depth_side[64, 64] + 2.0


def test_rooms_have_different_colours():
    scene = _two_rooms()
    renderer = SceneRenderer(scene)
    rgb0, d0 = renderer.render((1.5, 3.5), np.pi / 2)   # room 0, facing its north wall at 0.5 m
    rgb1, d1 = renderer.render((4.5, 3.5), np.pi / 2)   # room 1, same view
    np.testing.assert_allclose(d0, d1, atol=1e-5)       # same geometry ...
    diff = np.abs(rgb0[64, 64].astype(int) - rgb1[64, 64].astype(int))
    assert diff.max() > 30                              # ... different colours
    # The wall colour follows the room hue: the dominant channel matches the room's colour.
    for rgb, room in ((rgb0, scene.rooms[0]), (rgb1, scene.rooms[1])):
        assert np.argmax(rgb[64, 64]) == int(np.argmax(room.color))


def test_obstacle_is_seen_in_front_of_the_wall():
    labels = np.zeros((6, 3), dtype=int)
    box = Obstacle(xmin=3.2, ymin=1.2, xmax=3.8, ymax=1.8, height=1.0, material="wood_16mm")
    scene = build_scene(labels, obstacles=(box,))
    rgb, depth = SceneRenderer(scene).render((0.5, 1.5), 0.0)
    # Below the box top, the horizon-level view hits the near face at x = 3.2.
    low_row = next(v for v in range(64, 128) if CFG.eye_height + _row_slope(v) * 2.7 < 0.9)
    np.testing.assert_allclose(depth[low_row, 64], 2.7, atol=0.01)
    # At the horizon (z = 1.5, above the 1 m box) the ray passes over it to the wall.
    np.testing.assert_allclose(depth[64, 64], 5.5, atol=0.01)
    # Some row sees the box top: depth where eye + s * t = 1.0 lies inside [2.7, 3.3].
    top_rows = [v for v in range(64, 128)
                if 2.71 < (1.0 - CFG.eye_height) / _row_slope(v) < 3.29]
    assert top_rows
    v = top_rows[0]
    np.testing.assert_allclose(depth[v, 64], (1.0 - CFG.eye_height) / _row_slope(v), rtol=1e-4)
    assert scene.grid.node_at_cell(3, 1) == -1


def test_resolution_fov_and_max_depth():
    scene = build_scene(np.zeros((12, 3), dtype=int))
    cfg = CameraConfig(width=64, height=48, hfov_deg=60.0, max_depth=3.0)
    rgb, depth = SceneRenderer(scene, cfg).render((0.5, 1.5), 0.0)
    assert rgb.shape == (48, 64, 3) and depth.shape == (48, 64)
    assert depth.max() == pytest.approx(3.0) and depth.min() > 0
    np.testing.assert_allclose(cfg.focal, 32 / np.tan(np.radians(30)))


@pytest.mark.parametrize("field,value", [("width", 0), ("height", 2.5), ("hfov_deg", 180.0),
                                         ("max_depth", -1.0), ("eye_height", 0.0)])
def test_invalid_config(field, value):
    with pytest.raises(ConfigError, match=field):
        CameraConfig(**{field: value})


def test_eye_above_ceiling_is_rejected():
    with pytest.raises(ConfigError, match="eye_height"):
        SceneRenderer(generate_scene(0, preset="small"), CameraConfig(eye_height=3.0))


def test_view_cache_matches_renderer_and_renders_each_pose_once(monkeypatch):
    scene = generate_scene(1)
    views = CameraViews(scene)
    nodes = np.arange(16) % scene.grid.n_nodes
    headings = np.arange(16) % 4
    rgb, depth = views.views(nodes, headings)
    assert rgb.shape == (16, 128, 128, 3) and depth.shape == (16, 128, 128)
    ref_rgb, ref_depth = views.renderer.render_node(int(nodes[5]), int(headings[5]))
    np.testing.assert_array_equal(rgb[5], ref_rgb)
    np.testing.assert_array_equal(depth[5], ref_depth)
    assert np.isfinite(depth).all() and (depth > 0).all()
    # Warm, a batch is gathered from the cache, never rendered again (its speed: scripts/bench/camera.py).
    monkeypatch.setattr(views.renderer, "render", None)
    warm_rgb, warm_depth = views.views(nodes[::-1], headings[::-1])
    np.testing.assert_array_equal(warm_rgb, rgb[::-1])
    np.testing.assert_array_equal(warm_depth, depth[::-1])
    with pytest.raises(ConfigError, match="heading"):
        views.views([0], [4])
