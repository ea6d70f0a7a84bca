"""SI-SDR and STFT distance: agreement with torchmetrics, invariances, error cases."""

import numpy as np
import pytest
import scipy.signal
import torch
from torchmetrics.functional.audio import scale_invariant_signal_distortion_ratio

from m2h_ros.core.audio.metrics import all_finite, delayed, si_sdr, stft_distance
from m2h_ros.core.audio.stft import stft
from m2h_ros.errors import AudioError


def torchmetrics_si_sdr(estimate: np.ndarray, reference: np.ndarray) -> np.ndarray:
    return scale_invariant_signal_distortion_ratio(
        torch.from_numpy(estimate.astype(np.float64)), torch.from_numpy(reference.astype(np.float64)), zero_mean=True
    ).numpy()


def realistic_pairs(rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """A harmonic tone with a DC offset, and reverberated / noisy / offset estimates of it."""
    t = np.arange(16000) / 16000.0
    tone = sum(np.sin(2 * np.pi * 196.0 * k * t + k) / k for k in range(1, 8)) * np.hanning(16000) + 0.05
    decay = np.exp(-np.arange(4000) / 800.0) * rng.standard_normal(4000)
    decay[0] = 1.0
    reverberant = scipy.signal.fftconvolve(tone, decay * 0.3)[:16000]
    estimates = np.stack([
        reverberant,
        tone + 0.1 * rng.standard_normal(16000),
        0.4 * tone + 0.3,  # scaled, offset copy: perfect after zero-mean and scaling
        reverberant + 0.5 * rng.standard_normal(16000),
    ])
    return estimates, np.broadcast_to(tone, estimates.shape)


def test_si_sdr_matches_torchmetrics_random() -> None:
    rng = np.random.default_rng(0)
    reference = rng.standard_normal((4, 3, 16000)).astype(np.float32)
    estimate = reference + rng.uniform(0.05, 2.0, (4, 3, 1)) * rng.standard_normal((4, 3, 16000)).astype(np.float32)
    ours = si_sdr(estimate, reference)
    assert ours.shape == (4, 3)
    np.testing.assert_allclose(ours, torchmetrics_si_sdr(estimate, reference), atol=1e-3)
    assert np.ptp(ours) > 10  # the noise levels really differ


def test_si_sdr_matches_torchmetrics_realistic() -> None:
    estimates, reference = realistic_pairs(np.random.default_rng(1))
    ours = si_sdr(estimates, reference)
    np.testing.assert_allclose(ours, torchmetrics_si_sdr(estimates, reference), atol=1e-3)
    assert ours[2] > 100  # scaled + offset copy is perfect
    assert ours[3] < ours[0]  # extra noise lowers the score


def test_si_sdr_scale_invariance_and_scalar() -> None:
    rng = np.random.default_rng(3)
    reference = rng.standard_normal(8000)
    estimate = reference + 0.3 * rng.standard_normal(8000)
    base = si_sdr(estimate, reference)
    assert isinstance(base, float)
    assert si_sdr(7.5 * estimate, reference) == pytest.approx(base, abs=1e-9)
    assert si_sdr(estimate, 0.01 * reference) == pytest.approx(base, abs=1e-9)
    # 0.3 noise on unit-variance reference: about 10 log10(1 / 0.09) = 10.5 dB
    assert base == pytest.approx(10.46, abs=0.3)


def test_si_sdr_errors() -> None:
    x = np.ones(1000)
    with pytest.raises(AudioError, match="silent"):
        si_sdr(np.random.default_rng(0).standard_normal(1000), np.zeros(1000))
    with pytest.raises(AudioError, match="silent"):
        si_sdr(x, 3.0 * x)  # constant: silent once zero-meaned
    with pytest.raises(AudioError, match="NaN"):
        si_sdr(np.full(1000, np.nan), np.arange(1000.0))
    with pytest.raises(AudioError, match="NaN"):
        si_sdr(np.arange(1000.0), np.full(1000, np.inf))
    with pytest.raises(AudioError, match="shapes"):
        si_sdr(np.ones(10), np.ones(11))


def test_stft_distance_is_the_original_codes_mean_squared_real_imaginary_difference() -> None:
    rng = np.random.default_rng(4)
    estimate = np.abs(stft(rng.standard_normal((2, 16000)).astype(np.float32)))
    reference = stft(rng.standard_normal((2, 16000)).astype(np.float32))
    distance = stft_distance(estimate, reference)
    assert distance.shape == (2,)
    # The original's STFT_L2_distance, written out: the estimate takes the reference's phase, real and
    # imaginary parts are stacked, and the squared differences are averaged.
    phase = np.angle(reference.astype(np.complex128))
    gt = np.abs(reference.astype(np.complex128))
    pred = estimate.astype(np.float64)
    stacked = [np.stack([g * np.cos(p) - e * np.cos(p), g * np.sin(p) - e * np.sin(p)])
               for g, e, p in zip(gt, pred, phase)]
    np.testing.assert_allclose(distance, [np.mean(d**2) for d in stacked], rtol=1e-6)
    assert stft_distance(np.abs(reference[0]), reference[0]) == 0.0
    # not scale invariant: doubling both quadruples it
    assert stft_distance(2 * estimate[0], 2 * reference[0]) == pytest.approx(4 * distance[0])
    with pytest.raises(AudioError, match="NaN"):
        stft_distance(estimate[0] * np.nan, reference[0])
    with pytest.raises(AudioError, match="shapes"):
        stft_distance(estimate[0], reference)
    with pytest.raises(AudioError, match="magnitude"):
        stft_distance(reference[0], reference[0])


@pytest.mark.parametrize("dtype", [np.float32, np.float64, np.complex64, np.complex128])
def test_all_finite_is_numpys_isfinite_for_every_layout(dtype) -> None:
    rng = np.random.default_rng(5)
    x = rng.standard_normal((3, 5, 4)).astype(dtype)
    if np.iscomplexobj(x):
        x += 1j * rng.standard_normal(x.shape)
    for bad in (np.nan, np.inf, -np.inf, complex(0, np.nan), complex(np.inf, 0)):
        if isinstance(bad, complex) and not np.iscomplexobj(x):
            continue
        for view in (lambda a: a, lambda a: a.transpose(2, 0, 1), lambda a: a[:, ::2], lambda a: a[1, 2, 3]):
            y = x.copy()
            assert all_finite(view(y)) and np.all(np.isfinite(view(y)))
            y[1, 2, 3] = bad
            assert not all_finite(view(y)), (bad, view(y).shape)


def test_delayed_shifts_with_zeros_in_front() -> None:
    x = np.arange(1.0, 7.0)
    np.testing.assert_array_equal(delayed(x, 2), [0, 0, 1, 2, 3, 4])
    np.testing.assert_array_equal(delayed(x, 0), x)
    np.testing.assert_array_equal(delayed(x, 9), np.zeros(6))
    batch = np.stack([x, 10 * x]).astype(np.float32)
    out = delayed(batch, np.array([1, 3]))
    assert out.dtype == np.float32
    np.testing.assert_array_equal(out, [[0, 1, 2, 3, 4, 5], [0, 0, 0, 10, 20, 30]])
    # a delayed copy of a signal scores far better against the delay-aligned reference
    rng = np.random.default_rng(1)
    dry = rng.standard_normal(4000)
    heard = delayed(0.3 * dry, 37) + 0.01 * rng.standard_normal(4000)
    assert si_sdr(heard, delayed(dry, 37)) > 25 > 0 > si_sdr(heard, dry)
    for bad in (-1, 1.5, np.array([2, -3])):
        with pytest.raises(AudioError, match="non-negative whole samples"):
            delayed(batch, bad)
