"""Viewer: top-down and episode PNGs, camera view files."""

import numpy as np
import pytest
from matplotlib.figure import Figure
from matplotlib.image import imread

from m2h_ros.core.world.camera import CameraConfig, CameraViews
from m2h_ros.core.world.scene import generate_scene
from m2h_ros.core.world.viewer import camera_strip, draw_scene, plot_episode, save_camera_views
from m2h_ros.errors import ConfigError


@pytest.fixture(scope="module")
def scene():
    return generate_scene(2)


def test_draw_scene_draws_every_wall_and_obstacle(scene):
    ax = Figure().subplots()
    path = [(0, 0), (int(scene.grid.forward[0, 0]), 1)]
    draw_scene(ax, scene, sources=[(scene.grid.positions[3], "speech"),
                                   (scene.grid.positions[7], "background", "distractor")], path=path)
    assert len(ax.lines) == len(scene.walls) + 1            # walls + the path line
    assert len(ax.patches) == len(scene.rooms) + len(scene.obstacles)
    assert ax.get_xlim()[1] > scene.size[0]


def test_plot_episode_with_and_without_trace(scene, tmp_path):
    sources = [(scene.grid.positions[1], "music", "target")]
    path = [(n, 0) for n in scene.grid.shortest_path(0, 5)]
    plain = plot_episode(scene, sources=sources, path=path, out_png=tmp_path / "a.png")
    traced = plot_episode(scene, sources=sources, path=path, si_sdr=np.linspace(-3, 4, len(path)),
                          out_png=tmp_path / "sub" / "b.png")
    assert imread(traced).shape[1] > imread(plain).shape[1]   # the trace panel widens the figure
    with pytest.raises(ConfigError, match="category"):
        plot_episode(scene, sources=[((1, 1), "noise")], path=path, out_png=tmp_path / "c.png")


def test_save_camera_views_round_trips_rgb(scene, tmp_path):
    views = CameraViews(scene, CameraConfig(width=32, height=24))
    named = {"front": views.view(0, 0), "left": views.view(0, 1)}
    files = save_camera_views(named, tmp_path)
    assert sorted(f.name for f in files) == ["front_depth.png", "front_rgb.png",
                                             "left_depth.png", "left_rgb.png"]
    back = imread(tmp_path / "front_rgb.png")
    np.testing.assert_array_equal((back[..., :3] * 255).round().astype(np.uint8), named["front"][0])
    assert imread(tmp_path / "left_depth.png").shape[:2] == (24, 32)
    assert camera_strip(list(named.values()), out_png=tmp_path / "strip.png").exists()
