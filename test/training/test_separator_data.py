"""Separator training data drawn on the fly: layout, content, augmentation, determinism over workers."""

import dataclasses

import numpy as np
import pytest
import torch
from torch.utils.data import DataLoader

from m2h_ros.core.audio.stft import from_slices, stft, to_slices
from m2h_ros.core.sounds.library import TARGET_CATEGORIES
from m2h_ros.core.world.env import BatchEnv
from m2h_ros.errors import ConfigError
from m2h_ros.training.separator_data import (
    EQ_COMPONENTS,
    SPEED_STEPS,
    BatchSource,
    SeparatorStream,
    StreamConfig,
    build_banks,
    colouring_gains,
    fixed_set,
    policy_actions,
    slow_down,
    source_subset,
    stream_scenes,
    walk,
)


def sliced(array) -> torch.Tensor:
    return torch.from_numpy(np.ascontiguousarray(to_slices(np.asarray(array, np.float32), n_slices=16)))


@pytest.fixture(scope="module")
def plain(small_sequences):
    """The stream without augmentation: the same episodes, walks and actions."""
    return dataclasses.replace(small_sequences, gain_db=0.0, noise_levels=(), noise_fraction=0.0)


def test_layout(small_stream, small_sequences, folder_library):
    batch = BatchSource(small_stream, folder_library).batch(0)
    assert batch.index == 0
    assert batch.mixture.shape == batch.share.shape == (4, 1, 32, 32, 32) and batch.mixture.dtype == torch.float32
    assert batch.monaural.shape == (4, 16, 32, 32) and batch.class_index.shape == (4,)
    assert set(batch.class_index.tolist()) <= set(range(len(TARGET_CATEGORIES)))
    assert (batch.mixture >= 0).all() and (batch.share >= 0).all() and (batch.power > 0).all()
    sequences = BatchSource(small_sequences, folder_library).batch(0)
    mixture, share, monaural, classes = sequences.observations()
    assert sequences.mixture.shape[:2] == (3, 3) and mixture.shape == (9, 32, 32, 32)
    torch.testing.assert_close(monaural[3:6], sequences.monaural[1:2].expand(3, -1, -1, -1))
    assert classes.tolist() == np.repeat(sequences.class_index.numpy(), 3).tolist()
    # The mixture changes as the agent moves and turns.
    assert not torch.equal(sequences.mixture[0, 0], sequences.mixture[0, -1])


def test_unaugmented_batch_is_what_the_environment_renders(plain, folder_library):
    source = BatchSource(plain, folder_library)
    batch, plan = source.batch(2), source.plan(2)
    env = BatchEnv(plan.episodes, folder_library, n_envs=plain.batch_size, config=plain.env, autoreset=False)
    obs, info = env.reset(episodes=plan.episodes)
    for step in range(plain.steps):
        if step:
            obs, _, _, _, info = env.step(plan.actions[:, step - 1])
        torch.testing.assert_close(batch.mixture[:, step], sliced(np.abs(stft(obs["audio"]))), rtol=1e-4, atol=1e-3)
        torch.testing.assert_close(batch.share[:, step], sliced(np.abs(stft(info["target_binaural"] / 2))),
                                   rtol=1e-4, atol=1e-3)
    torch.testing.assert_close(batch.monaural, sliced(np.abs(stft(info["target_monaural"]))[:, None]),
                               rtol=1e-4, atol=1e-3)
    assert batch.class_index.tolist() == [TARGET_CATEGORIES.index(e.target_category) for e in plan.episodes]


def test_walk_follows_the_environment(plain, folder_library):
    episode = BatchSource(plain, folder_library).plan(0).episodes[0]
    actions = policy_actions(np.random.default_rng(5), 12)
    env = BatchEnv([episode], folder_library, n_envs=1, config=plain.env, autoreset=False)
    obs, _ = env.reset(episodes=[episode])
    for action in actions:
        obs, *_ = env.step(np.array([action]))
    assert walk(episode.scene().grid, episode.start_node, episode.start_heading, actions) == \
        (int(obs["node"][0]), int(obs["heading"][0]))


def test_gains_scale_the_target_and_its_share(small_sequences, plain, folder_library):
    gained_config = dataclasses.replace(plain, gain_db=small_sequences.gain_db)
    gained, base = BatchSource(gained_config, folder_library).batch(1), BatchSource(plain, folder_library).batch(1)
    ratio = (gained.monaural.sum(dim=(1, 2, 3)) / base.monaural.sum(dim=(1, 2, 3))).numpy()
    db = 20 * np.log10(ratio)
    assert (np.abs(db) <= gained_config.gain_db + 1e-3).all() and np.ptp(db) > 0.1
    share_ratio = (gained.share.sum(dim=(1, 2, 3, 4)) / base.share.sum(dim=(1, 2, 3, 4))).numpy()
    np.testing.assert_allclose(share_ratio, ratio, rtol=1e-4)
    assert not torch.allclose(gained.mixture, base.mixture)


def test_colouring_curves_follow_their_cosines():
    flat = colouring_gains(np.zeros((1, EQ_COMPONENTS)), np.zeros((1, EQ_COMPONENTS)), 16000, 16000)
    np.testing.assert_array_equal(flat, 1.0)
    # One component of 6 dB: +6 dB at the bottom of the band, -6 dB at Nyquist, 0 dB in the log middle.
    curve = colouring_gains(np.array([[6.0, 0.0, 0.0]]), np.zeros((1, EQ_COMPONENTS)), 16000, 16000)[0]
    db = 20 * np.log10(curve)
    middle = int(round(np.sqrt(60.0 * 8000.0)))  # 1 Hz bins
    assert db[0] == pytest.approx(6.0, abs=1e-4) and db[-1] == pytest.approx(-6.0, abs=1e-4)
    assert db[middle] == pytest.approx(0.0, abs=0.01) and np.all(np.diff(db[60:]) <= 1e-6)


def test_colouring_shapes_the_target_and_its_share_alike(plain, folder_library):
    coloured_config = dataclasses.replace(plain, eq_db=6.0)
    source = BatchSource(coloured_config, folder_library)
    coloured, base, plan = source.batch(1), BatchSource(plain, folder_library).batch(1), source.plan(1)
    # Everything but the colouring is drawn as before.
    assert plan.episodes == BatchSource(plain, folder_library).plan(1).episodes
    stft_config = plain.env.stft
    n, rate, n_slices = stft_config.clip_samples, stft_config.sample_rate, stft_config.n_freq_slices
    expected_db = 20 * np.log10(colouring_gains(plan.colouring[:, 0, 0], plan.colouring[:, 0, 1], n, rate))
    monaural = [from_slices(batch.monaural, n_slices=n_slices)[:, 0].sum(-1).numpy() for batch in (coloured, base)]
    share = [from_slices(batch.share, n_slices=n_slices).sum((1, 2, -1)).numpy() for batch in (coloured, base)]
    bins = np.fft.rfftfreq(stft_config.n_fft, 1 / rate)[:monaural[0].shape[1]]
    for row in range(plain.batch_size):
        want = np.interp(bins, np.fft.rfftfreq(n, 1 / rate), expected_db[row])
        for pair in (monaural, share):
            energetic = pair[1][row] > 0.05 * pair[1][row].max()  # bins where the ratio is not noise
            got = 20 * np.log10(pair[0][row][energetic] / pair[1][row][energetic])
            assert np.median(np.abs(got - want[energetic])) < 0.5 and np.ptp(want) > 1.0
    assert not torch.allclose(coloured.mixture, base.mixture)


def test_slow_down_scales_every_frequency_and_keeps_the_length():
    rate = 16000
    t = np.arange(rate) / rate
    tones = np.stack([np.sin(2 * np.pi * 1000 * t), np.sin(2 * np.pi * 3000 * t)]).astype(np.float32)
    np.testing.assert_array_equal(slow_down(tones, SPEED_STEPS), tones)  # speed 1: untouched
    slowed = slow_down(tones, 48)  # speed 0.75
    assert slowed.shape == tones.shape and slowed.dtype == np.float32
    peaks = np.abs(np.fft.rfft(slowed * np.hanning(rate), axis=-1)).argmax(axis=-1)  # 1 Hz bins
    assert peaks.tolist() == [750, 2250]
    # y(t) = x(0.75 t): the first three quarters of the signal fill it, to its last sample.
    np.testing.assert_allclose(slowed[:, ::4][:, 100:-20], tones[:, ::3][:, 100:len(slowed[0, ::4]) - 20], atol=2e-3)
    assert np.abs(slowed[:, -50:]).max() > 0.9


def test_slow_down_applies_one_speed_to_every_signal_of_a_sequence(plain, folder_library):
    slowed_config = dataclasses.replace(plain, speed_min=0.8)
    source = BatchSource(slowed_config, folder_library)
    slowed, base, plan = source.batch(1), BatchSource(plain, folder_library).batch(1), source.plan(1)
    assert plan.episodes == BatchSource(plain, folder_library).plan(1).episodes  # drawn after the rest
    assert plan.speeds.min() >= 0.8 * SPEED_STEPS and plan.speeds.max() <= SPEED_STEPS and np.ptp(plan.speeds) > 0
    n_slices, rate = plain.env.stft.n_freq_slices, plain.env.stft.sample_rate
    bins = np.fft.rfftfreq(plain.env.stft.n_fft, 1 / rate)

    def centroid(spectra):  # (B, F, frames) magnitudes -> spectral centroid per row, Hz
        power = spectra.sum(-1) ** 2
        return (power * bins[:power.shape[1]]).sum(1) / power.sum(1)

    speed = plan.speeds / SPEED_STEPS
    for field in ("monaural", "share"):
        spectra = [from_slices(getattr(b, field), n_slices=n_slices) for b in (slowed, base)]
        spectra = [x.flatten(1, -3).sum(1).numpy() if field == "share" else x[:, 0].numpy() for x in spectra]
        np.testing.assert_allclose(centroid(spectra[0]) / centroid(spectra[1]), speed, rtol=0.05)


def test_noise_has_the_drawn_level(plain, folder_library):
    noisy_config = dataclasses.replace(plain, noise_levels=(0.3,), noise_fraction=1.0)
    noisy, clean = BatchSource(noisy_config, folder_library).batch(0), BatchSource(plain, folder_library).batch(0)
    # White noise of std 0.3 x the clean RMS adds 9% to the mixture's power.
    np.testing.assert_allclose((noisy.power / clean.power).numpy(), 1.09, atol=0.01)
    torch.testing.assert_close(noisy.share, clean.share)  # the target is not noisy
    half = dataclasses.replace(noisy_config, noise_fraction=0.5)
    ratios = np.concatenate([(BatchSource(half, folder_library).batch(i).power
                              / BatchSource(plain, folder_library).batch(i).power).numpy().ravel() for i in range(4)])
    assert 0 < np.sum(ratios > 1.05) < len(ratios) and np.all((np.abs(ratios - 1) < 1e-5) | (ratios > 1.05))


def test_batches_are_a_function_of_their_index_for_any_worker_count(small_stream, folder_library):
    source = BatchSource(small_stream, folder_library)
    alone = [source.batch(i) for i in range(2, 6)]
    again = BatchSource(small_stream, folder_library).batch(4)
    torch.testing.assert_close(again.mixture, alone[2].mixture, rtol=0, atol=0)
    for workers in (0, 2):
        loaded = list(DataLoader(SeparatorStream(BatchSource(small_stream, folder_library), 2, 6), batch_size=None,
                                 num_workers=workers))
        assert [b.index for b in loaded] == [2, 3, 4, 5]
        for got, expected in zip(loaded, alone):
            for name in ("mixture", "share", "monaural", "class_index", "power"):
                torch.testing.assert_close(getattr(got, name), getattr(expected, name), rtol=0, atol=0)
    assert not torch.equal(alone[0].mixture, alone[1].mixture)
    other_seed = BatchSource(dataclasses.replace(small_stream, seed=1), folder_library).batch(2)
    assert not torch.equal(other_seed.mixture, alone[0].mixture)
    assert [b.index for b in fixed_set(source, 2, progress=False)] == [0, 1]


def test_scenes_limit_the_draws(small_stream, folder_library):
    first_two = dataclasses.replace(small_stream, scenes=2)
    indices = {e.scene_index for i in range(6) for e in BatchSource(first_two, folder_library).plan(i).episodes}
    assert indices == {0, 1}
    with pytest.raises(ConfigError, match="scenes"):
        BatchSource(dataclasses.replace(small_stream, scenes=99), folder_library)


def test_source_subsets_limit_placement_and_the_banks_to_build(small_stream, folder_library, tmp_path):
    limited = dataclasses.replace(small_stream, source_nodes=4, scenes=3)
    source = BatchSource(limited, folder_library)
    for i in range(4):
        for episode in source.plan(i).episodes:
            subset = source_subset(episode.scene(), 4)
            assert set(episode.source_nodes) <= set(subset.tolist())
    scene = stream_scenes(limited, limited.episodes[0])[0]
    np.testing.assert_array_equal(source_subset(scene, 4), source_subset(scene, 4))  # same for every stream
    assert source_subset(scene, scene.grid.n_nodes) is None
    assert build_banks(limited, cache_dir=tmp_path, workers=1, progress=False) == 3 * 4
    assert build_banks(limited, cache_dir=tmp_path, workers=1, progress=False) == 0  # all cached


def test_config_validation(small_stream):
    with pytest.raises(ConfigError, match="batch_size"):
        dataclasses.replace(small_stream, batch_size=1)
    with pytest.raises(ConfigError, match="steps"):
        dataclasses.replace(small_stream, steps=30)  # near-target episodes have 20 steps
    with pytest.raises(ConfigError, match="episodes"):
        StreamConfig(episodes=())
    with pytest.raises(ConfigError, match="noise_fraction"):
        dataclasses.replace(small_stream, noise_levels=(), noise_fraction=0.5)
    with pytest.raises(ConfigError, match="noise_levels"):
        dataclasses.replace(small_stream, noise_levels=(-0.1,))
    with pytest.raises(ConfigError, match="scenes"):
        dataclasses.replace(small_stream, scenes=0)
    with pytest.raises(ConfigError, match="source_nodes"):
        dataclasses.replace(small_stream, source_nodes=0)
    with pytest.raises(ConfigError, match="gain_db"):
        dataclasses.replace(small_stream, gain_db=-1.0)
    with pytest.raises(ConfigError, match="eq_db"):
        dataclasses.replace(small_stream, eq_db=float("nan"))
    with pytest.raises(ConfigError, match="speed_min"):
        dataclasses.replace(small_stream, speed_min=0.2)
    with pytest.raises(ConfigError, match="mic_noise"):
        dataclasses.replace(small_stream, env=dataclasses.replace(small_stream.env, mic_noise=0.1))
    with pytest.raises(ConfigError, match="n_distractors"):
        dataclasses.replace(small_stream, episodes=(small_stream.episodes[0],
                                                    dataclasses.replace(small_stream.episodes[1], n_distractors=2)))
    training, validation = StreamConfig.training(), StreamConfig.validation()
    assert training.gain_db > 0 and training.noise_fraction > 0 and training.episodes[0].scene_split == "train"
    assert validation.gain_db == 0 and validation.noise_fraction == 0 and validation.episodes[0].sound_split == "unheard"
