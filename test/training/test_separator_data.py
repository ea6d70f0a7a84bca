"""Separator datasets recorded from the simulator: layout, content, determinism, caching."""

import dataclasses

import numpy as np
import pytest

from m2h_ros.core.audio.stft import stft
from m2h_ros.core.sounds.library import TARGET_CATEGORIES
from m2h_ros.core.world.episodes import MOVE_FORWARD, TURN_LEFT, TURN_RIGHT, EpisodeConfig, episodes_for
from m2h_ros.errors import ConfigError
from m2h_ros.training import separator_data
from m2h_ros.training.separator_data import (
    SeparatorDataConfig,
    policy_actions,
    separator_dataset,
    variant_episodes,
)


@pytest.fixture
def dataset(small_train_set):
    return small_train_set


def test_layout_and_dtypes(dataset, small_train_data):
    s, t = small_train_data.n_sequences, small_train_data.steps
    assert (s, t) == (10, 4) and dataset.n_samples == 40
    assert dataset.mixture_logmag.shape == (s, t, 2, 512, 32) and dataset.mixture_logmag.dtype == np.float16
    assert dataset.target_binaural.shape == (s, t, 2, 512, 32) and dataset.target_binaural.dtype == np.float16
    assert dataset.target_monaural.shape == (s, 512, 32) and dataset.target_monaural.dtype == np.float16
    assert set(dataset.class_index.tolist()) <= {0, 1} and (dataset.n_sources == 2).all()
    for name in ("mixture_logmag", "target_binaural", "target_monaural", "mixture_power"):
        values = np.asarray(getattr(dataset, name), dtype=np.float32)
        assert np.isfinite(values).all() and (values >= 0).all(), name
    assert (dataset.mixture_power > 0).all()
    assert dataset.meta["n_sequences"] == s and dataset.meta["record_seconds"] >= 0


def test_content_matches_the_episodes(dataset, small_train_data, folder_library):
    episodes = [e for c in small_train_data.episodes for e in episodes_for(c, folder_library)]
    sequences = variant_episodes(episodes, folder_library, variants=2, seed=small_train_data.seed)
    for row in (0, 1, 7):
        episode = sequences[row]
        clip = folder_library.clip(episode.source_clips[0])
        expected = np.abs(stft(clip))
        np.testing.assert_allclose(dataset.target_monaural[row].astype(np.float32), expected,
                                   rtol=2e-3, atol=2e-3 * expected.max())
        assert dataset.class_index[row] == TARGET_CATEGORIES.index(episode.target_category)
    # A variant keeps the geometry and the categories, with its own clips and noise seed.
    base, variant = sequences[0], sequences[1]
    assert variant.source_nodes == base.source_nodes and variant.start_node == base.start_node
    assert variant.source_categories == base.source_categories and variant.seed != base.seed
    # The mixture changes as the agent moves and turns.
    assert not np.array_equal(dataset.mixture_logmag[0, 0], dataset.mixture_logmag[0, -1])


def test_rebuild_is_deterministic_and_cache_is_reused(dataset, small_train_data, folder_library, tmp_path,
                                                       monkeypatch):
    again = separator_dataset(small_train_data, folder_library, progress=False)  # same data dir: cached
    assert again.path == dataset.path
    monkeypatch.setenv("M2H_DATA_DIR", str(tmp_path))  # fresh dir: recorded again, other batching
    rebuilt = separator_dataset(small_train_data, folder_library, n_envs=3, rir_workers=1, progress=False)
    assert rebuilt.path != dataset.path
    for name in ("mixture_logmag", "target_binaural", "target_monaural", "class_index", "mixture_power"):
        np.testing.assert_array_equal(getattr(rebuilt, name), getattr(dataset, name), err_msg=name)


def test_policy_is_seeded_and_never_stops():
    a = policy_actions(0, 3, 50)
    np.testing.assert_array_equal(a, policy_actions(0, 3, 50))
    assert not np.array_equal(a, policy_actions(0, 4, 50))
    assert set(a.tolist()) == {MOVE_FORWARD, TURN_LEFT, TURN_RIGHT}


def test_config_validation_and_key(small_train_data, folder_library):
    with pytest.raises(ConfigError, match="sound_variants"):
        dataclasses.replace(small_train_data, sound_variants=0)
    with pytest.raises(ConfigError, match="steps"):
        dataclasses.replace(small_train_data, steps=30)  # near-target episodes have 20 steps
    with pytest.raises(ConfigError, match="episodes"):
        SeparatorDataConfig(episodes=())
    with pytest.raises(ConfigError, match="camera"):
        dataclasses.replace(small_train_data, env=dataclasses.replace(small_train_data.env, camera=True))
    other = dataclasses.replace(small_train_data, seed=1)
    assert other.key(folder_library) != small_train_data.key(folder_library)
    assert SeparatorDataConfig.training().n_sequences == (96 + 48) * 4
    assert isinstance(SeparatorDataConfig.validation().episodes[0], EpisodeConfig)
    assert separator_data.DATA_VERSION >= 1
