"""The Gan et al. sound locator's training: labels in the robot's frame, reproducible draws, a loss
that falls, a checkpoint that rebuilds itself with its metadata."""

import numpy as np
import pytest
import torch

from m2h_ros.core.world.episodes import EpisodeConfig
from m2h_ros.errors import CheckpointError, ConfigError
from m2h_ros.models.locator import LocatorConfig, load_locator, relative_offset
from m2h_ros.training.train_locator import LocatorTrainConfig, draw_set, train_locator

SMALL = dict(task="far_target", scene_preset="small", min_source_distance=3.0, far_min_distance=3.0)
TINY = LocatorConfig(bands=16, channels=(8, 8), hidden=16)


@pytest.fixture(scope="module")
def config(fast_env):
    return LocatorTrainConfig(model=TINY, train_episodes=EpisodeConfig(scene_split="train", sound_split="heard", **SMALL),
                              val_episodes=EpisodeConfig(scene_split="val", sound_split="unheard", **SMALL),
                              env=fast_env, samples=96, val_samples=32, epochs=3, batch_size=16, lr=3e-3, threads=1)


def test_offsets_are_forward_and_left_of_the_robot():
    pose = np.array([[1.0, 1.0, 0.0], [1.0, 1.0, np.pi / 2], [0.0, 0.0, np.pi]])
    target = np.array([[3.0, 1.0], [3.0, 1.0], [0.0, -2.0]])
    np.testing.assert_allclose(relative_offset(target, pose), [[2, 0], [0, -2], [0, 2]], atol=1e-6)


def test_draws_are_reproducible_and_labelled(config, folder_library):
    a = draw_set(config, config.train_episodes, folder_library, count=20, seed=4, progress=False)
    b = draw_set(config, config.train_episodes, folder_library, count=20, seed=4, progress=False)
    assert a.inputs.shape == (20, 3, 16, 32) and a.inputs.dtype == torch.float16
    assert torch.equal(a.inputs, b.inputs) and torch.equal(a.offsets, b.offsets)
    # At the target's node the offset is zero; elsewhere it is not.
    at = a.at_target > 0.5
    assert at.any() and (~at).any()
    assert torch.allclose(a.offsets[at], torch.zeros(2)) and (a.offsets[~at].norm(dim=1) > 0.5).all()


def test_training_lowers_the_loss_and_writes_a_checkpoint(config, folder_library, tmp_path):
    meta = train_locator(config, folder_library, out=tmp_path / "loc.pt", command="test", progress=False)
    history = meta["history"]
    assert len(history) == 3 and history[-1]["train_loss"] < history[0]["train_loss"]
    assert meta["final"]["val_loss"] == min(h["val_loss"] for h in history)
    assert len(meta["stop_rule"]) == 9 and all(0 <= r["recall"] <= 1 for r in meta["stop_rule"])
    loaded = load_locator(tmp_path / "loc.pt")
    assert loaded.config == TINY and loaded.metadata["command"] == "test"
    assert (tmp_path / "loc_loss.png").read_bytes()[:4] == b"\x89PNG"
    with pytest.raises(CheckpointError, match="train_locator.py"):
        load_locator(tmp_path / "missing.pt")


def test_config_validation(config):
    with pytest.raises(ConfigError):
        LocatorTrainConfig(at_target_fraction=1.0)
    with pytest.raises(ConfigError):
        LocatorConfig(bands=3)
