"""STFT front end: agreement with torch.stft/istft, shapes, slicing, phase reconstructions."""

import numpy as np
import pytest
import scipy.fft
import torch

from m2h_ros.core.audio.metrics import si_sdr
from m2h_ros.core.audio.stft import (
    DEFAULT_STFT,
    StftConfig,
    append_class_channel,
    from_slices,
    istft,
    log_magnitude,
    rebuild_ground_truth_phase,
    rebuild_mixture_phase,
    rebuild_with_phase,
    stft,
    to_slices,
)
from m2h_ros.errors import AudioError, ConfigError

WINDOW = torch.hann_window(1023)


def torch_stft(x: np.ndarray) -> np.ndarray:
    flat = torch.from_numpy(x.reshape(-1, x.shape[-1]))
    window = torch.hann_window(1023, dtype=flat.dtype)
    spec = torch.stft(flat, n_fft=1023, hop_length=512, win_length=1023, window=window, center=True,
                      pad_mode="reflect", return_complex=True)
    return spec.numpy().reshape(*x.shape[:-1], *spec.shape[-2:])


@pytest.fixture(scope="module")
def binaural() -> np.ndarray:
    rng = np.random.default_rng(1)
    return rng.standard_normal((3, 2, 16000)).astype(np.float32)


def test_config_documents_paper_window() -> None:
    cfg = DEFAULT_STFT
    assert (cfg.n_freq, cfg.n_frames, cfg.slice_shape) == (512, 32, (32, 32))
    assert cfg.window_ms == pytest.approx(63.9375)
    assert cfg.hop_ms == pytest.approx(32.0)
    np.testing.assert_allclose(cfg.window(), torch.hann_window(1023, dtype=torch.float64).numpy(), atol=1e-15)


@pytest.mark.parametrize("win_length", [1, 2, 255, 256, 400, 1023])
def test_window_is_scipys_periodic_hann_bit_for_bit(win_length: int) -> None:
    # Computed without scipy.signal (half a second of every process's start); the values must not move.
    import scipy.signal

    config = StftConfig(n_fft=1023, win_length=win_length, hop_length=min(win_length, 256))
    window = config.window()
    left = (1023 - win_length) // 2
    np.testing.assert_array_equal(window[left: left + win_length], scipy.signal.get_window("hann", win_length))
    assert not window[:left].any() and not window[left + win_length:].any()


@pytest.mark.parametrize("field,value",
                         [("n_fft", 0), ("hop_length", 2000), ("pad_mode", "wrap"), ("n_freq_slices", 7)])
def test_config_rejects_bad_values(field: str, value: object) -> None:
    with pytest.raises(ConfigError, match=field):
        StftConfig(**{field: value})


def test_config_dict_round_trip() -> None:
    assert StftConfig.from_dict(DEFAULT_STFT.to_dict()) == DEFAULT_STFT
    with pytest.raises(ConfigError, match="bogus"):
        StftConfig.from_dict({"bogus": 1})


def test_stft_matches_torch_batched(binaural: np.ndarray) -> None:
    spec = stft(binaural)
    assert spec.shape == (3, 2, 512, 32) and spec.dtype == np.complex64
    reference = torch_stft(binaural)
    assert np.abs(spec - reference).max() < 1e-5 * np.abs(reference).max()
    spec64 = stft(binaural.astype(np.float64))
    assert spec64.dtype == np.complex128
    np.testing.assert_allclose(spec64, torch_stft(binaural.astype(np.float64)), atol=1e-9)


def test_istft_matches_torch_and_inverts(binaural: np.ndarray) -> None:
    spec = stft(binaural)
    rebuilt = istft(spec, length=16000)
    assert rebuilt.shape == binaural.shape and rebuilt.dtype == np.float32
    torch_rebuilt = torch.istft(torch.from_numpy(spec.reshape(-1, 512, 32)), 1023, 512, 1023, WINDOW,
                                center=True, length=16000).numpy().reshape(binaural.shape)
    assert np.abs(rebuilt - torch_rebuilt).max() < 1e-5
    assert np.abs(rebuilt - binaural).max() < 1e-5
    # torch's default length (no length given): hop * (T - 1) + n_fft - 2 * (n_fft // 2)
    default = istft(spec)
    torch_default = torch.istft(torch.from_numpy(spec[0, 0]), 1023, 512, 1023, WINDOW, center=True).numpy()
    assert default.shape[-1] == torch_default.shape[-1] == 512 * 31 + 1
    np.testing.assert_allclose(default, binaural[..., : 512 * 31 + 1], atol=1e-5)


@pytest.mark.parametrize("config", [DEFAULT_STFT, StftConfig(pad_mode="constant"), StftConfig(center=False),
                                    StftConfig(n_fft=512, win_length=400, hop_length=160, n_freq_slices=1)])
@pytest.mark.parametrize("shape", [(16000,), (3, 2, 16000), (2, 1024)])
@pytest.mark.parametrize("dtype", [np.float32, np.float64])
def test_stft_equals_padded_sliding_window_rfft_bit_for_bit(config: StftConfig, shape: tuple, dtype) -> None:
    # The straightforward formulation (np.pad, a sliding window, rfft along the last axis, axes
    # swapped): the faster code must give the same bits, as one C-contiguous (..., F, T) array.
    x = np.random.default_rng(2).standard_normal(shape).astype(dtype)
    padded = np.pad(x, [(0, 0)] * (x.ndim - 1) + [(config.n_fft // 2,) * 2], mode=config.pad_mode) \
        if config.center else x
    frames = np.lib.stride_tricks.sliding_window_view(padded, config.n_fft, axis=-1)[..., ::config.hop_length, :]
    expected = np.swapaxes(scipy.fft.rfft(frames * config.window().astype(dtype), axis=-1), -1, -2)
    got = stft(x, config=config)
    assert got.dtype == expected.dtype and got.flags.c_contiguous
    np.testing.assert_array_equal(got, expected)
    strided = np.repeat(x, 2, axis=-1)[..., ::2]   # a non-contiguous view of the same samples
    np.testing.assert_array_equal(stft(strided, config=config), expected)


def test_stft_rejects_bad_input() -> None:
    with pytest.raises(AudioError, match="NaN"):
        stft(np.full(16000, np.nan, dtype=np.float32))
    with pytest.raises(AudioError, match="samples"):
        stft(np.zeros(100, dtype=np.float32))
    with pytest.raises(AudioError, match="float"):
        stft(np.zeros(16000, dtype=np.int16))


def test_slices_round_trip_and_channel_order(binaural: np.ndarray) -> None:
    features = log_magnitude(stft(binaural))
    sliced = to_slices(features)
    assert sliced.shape == (3, 32, 32, 32)
    # channel c * 16 + s holds bins [32 s, 32 s + 32) of input channel c
    np.testing.assert_array_equal(sliced[:, 1 * 16 + 5], features[:, 1, 160:192])
    np.testing.assert_array_equal(sliced[:, 3], features[:, 0, 96:128])
    np.testing.assert_array_equal(from_slices(sliced), features)
    # the same reshape works on torch tensors
    assert torch.equal(to_slices(torch.from_numpy(features)), torch.from_numpy(sliced))


def test_class_channel_appended_last(binaural: np.ndarray) -> None:
    x = append_class_channel(to_slices(log_magnitude(stft(binaural))), np.array([0, 1, 1]))
    assert x.shape == (3, 33, 32, 32) and x.dtype == np.float32
    np.testing.assert_array_equal(x[:, 32, 0, 0], [1.0, 2.0, 2.0])
    assert np.all(x[:, 32] == x[:, 32, :1, :1])
    single = append_class_channel(np.zeros((16, 32, 32), dtype=np.float32), 1)
    assert single.shape == (17, 32, 32) and np.all(single[16] == 2.0)


def harmonic(n: int = 16000, f0: float = 220.0) -> np.ndarray:
    t = np.arange(n) / 16000.0
    return sum(np.sin(2 * np.pi * f0 * k * t) / k for k in range(1, 6)).astype(np.float32)


def test_phase_reconstructions() -> None:
    rng = np.random.default_rng(2)
    target = harmonic()
    distractor = rng.standard_normal(16000).astype(np.float32) * 0.3
    # a binaural mixture whose two channels are the target plus a distractor
    mixture = np.stack([target + distractor, target + 0.5 * distractor])
    magnitude = np.abs(stft(target))
    # oracle magnitude + ground-truth phase rebuilds the target exactly
    exact = rebuild_ground_truth_phase(magnitude, target)
    assert si_sdr(exact, target) > 60
    # with the mixture's phase the reconstruction is good but worse than the oracle
    deployable = rebuild_mixture_phase(magnitude, mixture)
    assert deployable.shape == target.shape
    assert 5 < si_sdr(deployable, target) < si_sdr(exact, target)
    with pytest.raises(AudioError, match="binaural"):
        rebuild_mixture_phase(magnitude, target)


def test_rebuild_with_phase_is_magnitude_times_unit_phase() -> None:
    rng = np.random.default_rng(3)
    phase_spec = stft(rng.standard_normal((2, 16000)).astype(np.float32))
    phase_spec[0, 10, 4] = 0  # angle(0) = 0: the bin keeps the magnitude with phase 1
    magnitude = np.abs(stft(harmonic()))[None].repeat(2, axis=0)
    expected = istft(magnitude * np.exp(1j * np.angle(phase_spec)), length=16000)
    for mag in (magnitude, magnitude.astype(np.float64)):
        rebuilt = rebuild_with_phase(mag, phase_spec, length=16000)
        assert rebuilt.dtype == mag.dtype
        np.testing.assert_allclose(rebuilt, expected, atol=1e-5 * np.abs(expected).max())
