"""The target-location auxiliary task (its command-line weight and its loss's effect: test_teacher.py):
its labels are the target's offset in the robot's frame, a run with it resumes exactly and ships a
policy without the head, and a resume state written before the option existed still continues."""

import dataclasses

import numpy as np
import pytest
import torch

from m2h_ros.core.world.episodes import scene_at
from m2h_ros.core.world.navgrid import HEADING_STEPS, N_HEADINGS
from m2h_ros.errors import CheckpointError
from m2h_ros.models.policy import load_policy
from m2h_ros.training.location import target_offsets
from m2h_ros.training.ppo import train
from test_ppo import tiny
from test_teacher import _Episode


def test_offsets_are_the_target_in_the_robots_frame():
    grid = scene_at("test", "small", 0).grid
    rng = np.random.default_rng(0)
    nodes, headings = rng.integers(grid.n_nodes, size=30), rng.integers(N_HEADINGS, size=30)
    goals = rng.integers(grid.n_nodes, size=30)
    scene = scene_at("test", "small", 0)
    offsets = target_offsets([_Episode(scene, int(g)) for g in goals], nodes, headings)
    assert offsets.shape == (30, 2) and offsets.dtype == np.float32
    for slot in range(30):
        ahead = HEADING_STEPS[headings[slot]].astype(np.float64)  # the robot's forward unit vector
        left = np.array([-ahead[1], ahead[0]])
        world = grid.positions[goals[slot]] - grid.positions[nodes[slot]]
        np.testing.assert_allclose(offsets[slot], [world @ ahead, world @ left], atol=1e-5)


def test_a_run_with_the_location_term_resumes_exactly(fast_env, separator_path, folder_library, tmp_path):
    # The shipped pi^Q's recipe: the SI-SDR reward (its target STFTs are rebuilt on resuming), no final term.
    config = tiny(fast_env, separator_path, location_coef=1.0, train_refiner=False, quality_reward="si_sdr",
                  final_weight=0.0)
    whole = train(config, folder_library, out_dir=tmp_path / "whole", progress=False)
    train(config, folder_library, out_dir=tmp_path / "part", progress=False, stop_after=1)
    resumed = train(config, folder_library, out_dir=tmp_path / "part", progress=False)
    for name, tensor in whole.net.state_dict().items():
        torch.testing.assert_close(resumed.net.state_dict()[name], tensor, rtol=0, atol=0, msg=name)
    assert [h["location_loss"] for h in resumed.history] == pytest.approx([h["location_loss"] for h in whole.history],
                                                                          rel=1e-9)
    shipped = load_policy(whole.checkpoint, policy_kind="quality")  # the head is training's alone
    assert set(shipped.net.state_dict()) == set(whole.net.state_dict())


def test_a_resume_state_from_before_the_option_continues(fast_env, separator_path, folder_library, tmp_path):
    config = tiny(fast_env, separator_path, train_refiner=False)
    train(config, folder_library, out_dir=tmp_path / "run", progress=False, stop_after=1)
    path = tmp_path / "run" / "resume.pt"
    state = torch.load(path, weights_only=True)
    del state["config"]["location_coef"], state["location_head"]  # as written before it existed
    del state["config"]["env"]["spectrogram"]  # ... and before EnvConfig.spectrogram existed
    torch.save(state, path)
    assert len(train(config, folder_library, out_dir=tmp_path / "run", progress=False).history) == config.updates
    with pytest.raises(CheckpointError, match="other settings.*location_coef"):
        train(dataclasses.replace(config, location_coef=1.0, updates=config.updates + 1), folder_library,
              out_dir=tmp_path / "run", progress=False)
