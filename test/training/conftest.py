"""Fixtures of the training tests: the synthetic folder library (test/conftest.py), small scenes,
fast acoustics, and one data dir per session (datasets and RIR banks are built once)."""

import dataclasses
from pathlib import Path

import pytest

from m2h_ros.core.sounds.sources import sources_dir
from m2h_ros.core.world.env import EnvConfig
from m2h_ros.core.world.episodes import EpisodeConfig
from m2h_ros.training.separator_data import SeparatorDataConfig, SeparatorDataset, separator_dataset

SMALL = dict(scene_preset="small", min_source_distance=3.0)


@pytest.fixture(scope="session")
def training_data_dir(tmp_path_factory) -> Path:
    return tmp_path_factory.mktemp("training_data")


# The HRTF comes from the fetched sound sources of the real data dir, which _data_dir hides.
SOUND_SOURCES = sources_dir()


@pytest.fixture(autouse=True)
def _data_dir(monkeypatch, training_data_dir):
    monkeypatch.setenv("M2H_DATA_DIR", str(training_data_dir))
    monkeypatch.setenv("M2H_SOUND_SOURCES", str(SOUND_SOURCES))


@pytest.fixture(scope="session")
def fast_env(fast_acoustics) -> EnvConfig:
    """Fast acoustics (test/conftest.py), no camera: a small scene's source node in ~0.02 s."""
    return EnvConfig(camera=False, acoustics=fast_acoustics)


@pytest.fixture(scope="session")
def small_train_data(fast_env) -> SeparatorDataConfig:
    """5 episodes (3 near, 2 far) x 2 clip variants = 10 sequences of 4 observations."""
    return SeparatorDataConfig(episodes=(
        EpisodeConfig(task="near_target", scene_split="train", sound_split="heard", count=3, near_radius=2.0,
                      **SMALL),
        EpisodeConfig(task="far_target", scene_split="train", sound_split="heard", count=2, far_min_distance=3.0,
                      **SMALL)), sound_variants=2, steps=4, env=fast_env)


@pytest.fixture(scope="session")
def small_val_data(small_train_data) -> SeparatorDataConfig:
    episodes = tuple(dataclasses.replace(e, scene_split="val", sound_split="unheard") for e in small_train_data.episodes)
    return dataclasses.replace(small_train_data, episodes=episodes, sound_variants=1)


@pytest.fixture(scope="session")
def small_train_set(small_train_data, folder_library, training_data_dir) -> SeparatorDataset:
    with pytest.MonkeyPatch.context() as patch:
        patch.setenv("M2H_DATA_DIR", str(training_data_dir))
        return separator_dataset(small_train_data, folder_library, n_envs=4, progress=False)


@pytest.fixture(scope="session")
def separator_path(tmp_path_factory) -> Path:
    """An untrained tiny separator checkpoint (widths 8..16), enough to drive policy training."""
    import torch

    from m2h_ros.models.checkpoint import save_separator
    from m2h_ros.models.separator import Separator, SeparatorConfig

    torch.manual_seed(0)
    separator = Separator(SeparatorConfig(unet_channels=(8, 8, 16, 16, 16), refiner_hidden=8)).eval()
    return save_separator(tmp_path_factory.mktemp("separator") / "tiny.pt", separator, classes=("speech", "music"))
