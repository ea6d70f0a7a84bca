"""Fixtures of the training tests: the synthetic folder library (test/conftest.py), small scenes,
fast acoustics, and one data dir per session (RIR banks are built once)."""

import dataclasses
from pathlib import Path

import pytest

from m2h_ros.core.sounds.sources import sources_dir
from m2h_ros.core.world.env import EnvConfig
from m2h_ros.core.world.episodes import EpisodeConfig
from m2h_ros.training.separator_data import StreamConfig

SMALL = dict(scene_preset="small", min_source_distance=3.0)


@pytest.fixture(scope="session")
def training_data_dir(tmp_path_factory) -> Path:
    return tmp_path_factory.mktemp("training_data")


@pytest.fixture(scope="session", autouse=True)
def _sound_sources():
    """The KEMAR HRTF comes from the sound sources (unless libmysofa1 is installed): keep finding
    them where they are while the data dir points at a per-session folder."""
    with pytest.MonkeyPatch.context() as patch:
        patch.setenv("M2H_SOUND_SOURCES", str(sources_dir()))
        yield


@pytest.fixture(autouse=True)
def _data_dir(monkeypatch, training_data_dir):
    monkeypatch.setenv("M2H_DATA_DIR", str(training_data_dir))


@pytest.fixture(scope="session")
def fast_env(fast_acoustics) -> EnvConfig:
    """Fast acoustics (test/conftest.py), no camera: a small scene's source node in ~0.02 s."""
    return EnvConfig(camera=False, acoustics=fast_acoustics)


@pytest.fixture(scope="session")
def small_stream(fast_env) -> StreamConfig:
    """Small train scenes, heard sounds, near and far starts, batches of 4 single observations, augmented."""
    return StreamConfig(episodes=(
        EpisodeConfig(task="near_target", scene_split="train", sound_split="heard", near_radius=2.0, **SMALL),
        EpisodeConfig(task="far_target", scene_split="train", sound_split="heard", far_min_distance=3.0, **SMALL)),
        batch_size=4, steps=1, max_walk=3, gain_db=3.0, noise_levels=(0.05, 0.1), noise_fraction=0.5, env=fast_env)


@pytest.fixture(scope="session")
def small_sequences(small_stream) -> StreamConfig:
    """The same draws as sequences of 3 observations."""
    return dataclasses.replace(small_stream, batch_size=3, steps=3)


@pytest.fixture(scope="session")
def small_val_stream(small_stream) -> StreamConfig:
    """Small val scenes, unheard sounds, sequences of 3 observations, no augmentation."""
    episodes = tuple(dataclasses.replace(e, scene_split="val", sound_split="unheard") for e in small_stream.episodes)
    return dataclasses.replace(small_stream, episodes=episodes, batch_size=3, steps=3, gain_db=0.0,
                               noise_levels=(), noise_fraction=0.0)


@pytest.fixture(scope="session")
def separator_path(tmp_path_factory) -> Path:
    """An untrained tiny separator checkpoint (widths 8..16), enough to drive policy training."""
    import torch

    from m2h_ros.models.checkpoint import save_separator
    from m2h_ros.models.separator import Separator, SeparatorConfig

    torch.manual_seed(0)
    separator = Separator(SeparatorConfig(unet_channels=(8, 8, 16, 16, 16), refiner_hidden=8)).eval()
    return save_separator(tmp_path_factory.mktemp("separator") / "tiny.pt", separator, classes=("speech", "music"))
