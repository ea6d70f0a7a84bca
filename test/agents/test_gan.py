"""The Gan et al. baseline: its depth map sees walls where the grid has them, its planner goes around
them, and with a perfect locator it walks to the target and stops there."""

import dataclasses

import numpy as np
import pytest
import torch

from m2h_ros.agents.base import EpisodeStart
from m2h_ros.agents.gan import GanEtAl, OccupancyMap, move_toward
from m2h_ros.agents.registry import make_controller
from m2h_ros.agents.rollout import controller_observation
from m2h_ros.core.world.camera import CameraConfig, SceneRenderer
from m2h_ros.core.world.env import BatchEnv
from m2h_ros.core.world.episodes import MOVE_FORWARD, STOP, TURN_LEFT, TURN_RIGHT
from m2h_ros.core.world.navgrid import HEADING_STEPS, heading_index
from m2h_ros.errors import CheckpointError
from m2h_ros.models.locator import LocatorOutput, SoundLocator, load_locator, relative_offset, save_locator
from m2h_ros.models.runner import SeparationStep

F, T = 512, 32


@pytest.fixture(scope="module")
def locator_path(tmp_path_factory):
    torch.manual_seed(0)
    return save_locator(tmp_path_factory.mktemp("locator") / "locator.pt", SoundLocator())


def test_the_depth_map_blocks_only_moves_the_grid_blocks(small_episodes):
    scene = small_episodes(count=1, max_steps=5)[0].scene()
    grid, renderer = scene.grid, SceneRenderer(scene, CameraConfig())
    occupancy = OccupancyMap(CameraConfig())
    for node in range(grid.n_nodes):
        for heading in range(4):
            _, depth = renderer.render_node(node, heading)
            occupancy.add_depth(depth, np.array([*grid.positions[node], heading * np.pi / 2]))
    cells = {tuple(c) for c in grid.cells.tolist()}
    truly_blocked, found = 0, 0
    for node, cell in enumerate(grid.cells.tolist()):
        for heading, (dx, dy) in enumerate(HEADING_STEPS):
            blocked = grid.forward[node, heading] == node
            nxt = (cell[0] + int(dx), cell[1] + int(dy))
            seen = (*cell, heading) in occupancy.blocked_moves or nxt in occupancy.blocked_cells
            truly_blocked += blocked
            found += blocked and seen
            if seen:  # no false walls: what the map blocks, the grid blocks too
                assert blocked, (cell, heading)
    assert found >= 0.8 * truly_blocked  # and it finds most of the real ones
    assert not occupancy.blocked_cells & cells  # no free cell is marked an obstacle


def test_the_planner_goes_around_a_wall():
    occupancy = OccupancyMap()
    for y in range(-3, 4):  # a wall between x = 0 and x = 1, open at y = 4
        occupancy.block_move((0, y), 0)
    assert occupancy.first_move((0, 0), (0, 0)) is None
    assert occupancy.first_move((0, 0), (3, 0)) == 1  # up (+y) toward the opening, not into the wall
    occupancy.blocked_cells.add((0, 1))
    assert occupancy.first_move((0, 0), (3, 0)) == 3  # that way is shut too: down and around
    assert heading_index(np.pi / 2 + 0.01) == 1 and heading_index(-np.pi / 2) == 3


class TrueLocator(torch.nn.Module):
    """Answers with the offsets and Stop logits it was given for the coming call."""

    def forward(self, x):
        return LocatorOutput(torch.from_numpy(self.offsets), torch.from_numpy(self.stop_logits))


def test_with_a_perfect_locator_it_walks_to_the_target_and_stops(small_episodes, folder_library, env_config,
                                                                 locator_path):
    episodes = small_episodes(count=4, max_steps=30, task="far_target", seed=3)
    controller = GanEtAl(len(episodes), checkpoint=str(locator_path), replan_every=5)
    assert controller.model_files() == [locator_path]
    oracle = TrueLocator()
    controller.locator = dataclasses.replace(controller.locator, net=oracle)
    # Slots that end start wrapped-around episodes (autoreset); only their first episode counts.
    env = BatchEnv(episodes, folder_library, n_envs=len(episodes), config=dataclasses.replace(env_config, camera=True))
    zero = SeparationStep(np.zeros((4, 2, F, T), np.float32), np.zeros((4, F, T), np.float32),
                          np.zeros((4, F, T), np.float32))
    try:
        obs, info = env.reset()
        for slot, episode in enumerate(env.current_episodes):
            controller.reset(slot, EpisodeStart.of(episode))
        targets = np.array([env.scene_of(s).grid.positions[e.target_node] for s, e in enumerate(episodes)])
        done = np.zeros(len(episodes), bool)
        stopped_at_target = np.zeros(len(episodes), bool)
        for _ in range(30):
            oracle.offsets = relative_offset(targets, obs["pose"])
            oracle.stop_logits = np.where(info["at_target"], 10.0, -10.0).astype(np.float32)
            actions = controller.act(controller_observation(obs, zero, uses_separator=False))
            stopped_at_target |= (actions == STOP) & info["at_target"] & ~done
            assert not ((actions == STOP) & ~info["at_target"] & ~done).any()
            obs, _, terminated, truncated, info = env.step(actions)
            done |= terminated | truncated
            if done.all():
                break
    finally:
        env.close()
    assert stopped_at_target.all()


def test_it_builds_from_the_registry_and_names_a_missing_locator(tmp_path, locator_path):
    controller = make_controller("gan_et_al", 2, checkpoint=str(locator_path), replan_every=10)
    assert controller.uses_camera and not controller.uses_separator and controller.replan_every == 10
    assert load_locator(locator_path).config == controller.locator.config
    with pytest.raises(CheckpointError, match="train_locator.py"):
        make_controller("gan_et_al", 1, checkpoint=str(tmp_path / "none.pt"))


# What the environment's turns do to the heading (BatchEnv.step: left = +1 quarter turn, right = -1).
TURNED = {TURN_LEFT: +1, TURN_RIGHT: -1}


@pytest.mark.parametrize("start", range(4))
@pytest.mark.parametrize("wanted", range(4))
def test_the_planner_turns_the_short_way_toward_the_wanted_heading(start, wanted):
    heading, turns = start, 0
    while (action := move_toward(heading, wanted)) != MOVE_FORWARD:
        assert action in TURNED and turns < 4, (start, wanted, heading)
        heading, turns = (heading + TURNED[action]) % 4, turns + 1
    assert heading == wanted  # it moves forward only once facing the way the plan goes
    assert turns == min((wanted - start) % 4, (start - wanted) % 4)  # never three turns for one
