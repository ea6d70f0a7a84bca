"""The five nodes in imported worlds: a nav2 map drawn by a script and a mesh whose walls are not
axis-aligned, each played, recorded and scored as the main job does, and the bag checked for the world."""

from __future__ import annotations

import subprocess
import sys

import numpy as np
import pytest
from pipeline_helpers import bag_messages, node_env, run_pipeline, tiny_sets

from m2h_ros import topics
from scripts_as_modules import load_script

pytestmark = pytest.mark.graph
EPISODES = 3


@pytest.fixture(scope="module")
def apartment(tmp_path_factory):
    """The docs' example apartment as map_saver_cli would save it, turned 20 degrees in the map frame."""
    from m2h_ros.core.world.ros_map import write_ros_map
    from m2h_ros.core.world.sample_worlds import apartment_grid

    folder = tmp_path_factory.mktemp("apartment")
    write_ros_map(folder / "map.yaml", apartment_grid(yaw=np.radians(20.0)))
    return f"map:{folder / 'map.yaml'}"


@pytest.fixture(scope="module")
def turned_mesh(tmp_path_factory):
    """A generated test scene exported as a glb and turned 30 degrees: no wall on a lattice axis."""
    export = load_script("export_scene_mesh")
    from m2h_ros.core.world.mesh_camera import scene_mesh
    from m2h_ros.core.world.scene import load_split

    path = tmp_path_factory.mktemp("mesh") / "house.glb"
    path.write_bytes(export.export_bytes(export.turned(scene_mesh(load_split("test")[0]), 30.0), "glb"))
    return f"mesh:{path}"


def eval_bag(bag, world: str, out) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "m2h_ros.replay_cli", str(bag), "--out", str(out), "--no-plots",
                           "--world", world], capture_output=True, text=True, timeout=120, env=node_env(out))


@pytest.mark.parametrize("world_fixture", ["apartment", "turned_mesh"])
def test_three_episodes_run_recorded_and_scored_in_an_imported_world(world_fixture, request, small_library,
                                                                     small_data_dir, tmp_path):
    from m2h_ros.core.world.worlds import load_world

    spec = request.getfixturevalue(world_fixture)
    world = load_world(spec)
    result = run_pipeline(tmp_path, small_data_dir, "--world", spec, "--episodes", str(EPISODES),
                          *tiny_sets(camera_size=64))
    assert result.returncode == 0, result.stdout + result.stderr
    assert f"| move2hear | near_target | unheard | {EPISODES} |" in result.stdout
    messages = bag_messages(tmp_path / "bag")
    infos = messages["/" + topics.EPISODE]
    assert len(infos) == EPISODES and {m.scene_id for m in infos} == {world.world_id}
    # /map is the world's own raster: a nav2 map's cells at its resolution, origin and turn.
    grid = messages["/" + topics.MAP][-1]
    assert (grid.info.width, grid.info.height) == (world.plan.cells.shape[1], world.plan.cells.shape[0])
    assert grid.info.resolution == pytest.approx(world.plan.resolution)
    assert (grid.info.origin.position.x, grid.info.origin.position.y) == pytest.approx(world.plan.origin)
    assert 2 * np.arctan2(grid.info.origin.orientation.z, grid.info.origin.orientation.w) == \
        pytest.approx(world.plan.yaw)
    np.testing.assert_array_equal(np.asarray(grid.data, np.int8).reshape(world.plan.cells.shape), world.plan.cells)
    # Every pose the sim reported is where its node is in the world.
    poses = messages["/" + topics.AGENT_POSE]
    xy = np.array([[m.pose.position.x, m.pose.position.y] for m in poses])
    np.testing.assert_allclose(xy, world.grid.positions[[m.node for m in poses]], atol=1e-6)
    scored = eval_bag(tmp_path / "bag", spec, tmp_path / "eval")
    assert scored.returncode == 0, scored.stdout + scored.stderr
    # The run video draws the plan turned as the map is.
    from m2h_ros.video import read_episode

    assert read_episode(tmp_path / "bag", 0).grid[2] == pytest.approx(world.plan.yaw)


def test_a_bag_scored_against_another_world_is_named(apartment, small_library, small_data_dir, tmp_path):
    from m2h_ros.core.world.ros_map import write_ros_map
    from m2h_ros.core.world.sample_worlds import apartment_grid

    result = run_pipeline(tmp_path / "run", small_data_dir, "--world", apartment, "--episodes", "1",
                          "--controller", "random", *tiny_sets())
    assert result.returncode == 0, result.stdout + result.stderr
    other = tmp_path / "other" / "map.yaml"
    write_ros_map(other, apartment_grid(yaw=np.radians(20.0), noise=0.2))  # the same flat, mapped again
    scored = eval_bag(tmp_path / "run" / "bag", f"map:{other}", tmp_path / "eval")
    assert scored.returncode == 3, scored.stdout + scored.stderr
    assert "scored against another world" in scored.stdout and str(other) in scored.stdout

