"""MIT KEMAR HRTF loading: geometry conventions, diffuse-field equalisation, ILD and ITD."""

import numpy as np
import pytest

from m2h_ros.core.world.hrtf import diffuse_field_power, load_kemar, third_octave_smooth
from m2h_ros.errors import CacheError, ConfigError


def _itd_seconds(left: np.ndarray, right: np.ndarray, sample_rate: int, upsample: int = 8) -> float:
    """Lag (s) by which the right ear lags the left, from the cross-correlation peak (upsampled)."""
    n = (len(left) + len(right)) * upsample
    spec = np.fft.rfft(right, n // upsample) * np.conj(np.fft.rfft(left, n // upsample))
    xcorr = np.fft.irfft(spec, n)
    lag = int(np.argmax(xcorr))
    lag = lag - n if lag > n // 2 else lag
    return lag / (sample_rate * upsample)


def test_kemar_shapes_and_normalisation():
    hrtf = load_kemar(16000)
    assert hrtf.hrirs.shape[:2] == (710, 2) and hrtf.hrirs.dtype == np.float32
    # 512 taps at 44.1 kHz, trimmed, at 16 kHz (~178), plus the 128-tap equaliser.
    assert 250 < hrtf.hrirs.shape[2] < 320
    assert np.allclose(np.linalg.norm(hrtf.directions, axis=1), 1.0)
    assert hrtf.weights.sum() == pytest.approx(1.0) and (hrtf.weights > 0).all()
    # The horizontal ring (-5..5 deg) holds its solid-angle share of the measured sphere (-45..90 deg).
    horizontal = np.abs(hrtf.directions[:, 2]) < 1e-6
    share = 2 * np.sin(np.deg2rad(5)) / (1 + np.sin(np.deg2rad(45)))
    assert hrtf.weights[horizontal].sum() == pytest.approx(share)
    energy = np.einsum("d,de->", hrtf.weights, (hrtf.hrirs.astype(np.float64) ** 2).sum(-1)) / 2
    assert energy == pytest.approx(1.0, rel=1e-3)
    assert 0 < hrtf.centre_delay < 20


def test_left_source_is_louder_and_earlier_in_left_ear():
    hrtf = load_kemar(16000)
    left_index = int(hrtf.nearest(np.array([0.0, 3.0, 0.0])))
    assert np.allclose(hrtf.directions[left_index], [0, 1, 0], atol=1e-6)
    left, right = hrtf.hrirs[left_index].astype(np.float64)
    ild_db = 10 * np.log10((left**2).sum() / (right**2).sum())
    itd = _itd_seconds(left, right, 16000)
    assert ild_db > 5.0
    assert 0.3e-3 < itd < 0.85e-3
    front = hrtf.hrirs[int(hrtf.nearest(np.array([1.0, 0.0, 0.0])))].astype(np.float64)
    assert abs(_itd_seconds(front[0], front[1], 16000)) < 0.07e-3


def _diffuse_field_db(hrtf, n_fft=1024):
    freqs = np.fft.rfftfreq(n_fft, 1.0 / hrtf.sample_rate)
    power = third_octave_smooth(diffuse_field_power(hrtf.hrirs, hrtf.weights, n_fft), freqs)
    band = (freqs >= 200) & (freqs <= 6000)
    return 10 * np.log10(power[band])


def test_equalised_diffuse_field_is_flat_raw_is_not():
    flat = _diffuse_field_db(load_kemar(16000))
    assert flat.max() - flat.min() < 3.0
    raw = _diffuse_field_db(load_kemar(16000, equalise=False))
    assert raw.max() - raw.min() > 12.0  # the raw set's low-frequency deficit


@pytest.mark.parametrize("side", [1.0, -1.0])
def test_equalisation_keeps_itd_at_90_degrees(side):
    itds = []
    for equalise in (True, False):
        hrtf = load_kemar(16000, equalise=equalise)
        index = int(hrtf.nearest(np.array([0.0, side, 0.0])))
        assert np.allclose(hrtf.directions[index], [0, side, 0], atol=1e-6)
        left, right = hrtf.hrirs[index].astype(np.float64)
        itds.append(_itd_seconds(left, right, 16000))
    assert side * itds[0] > 0.3e-3  # the far ear lags
    assert abs(itds[0] - itds[1]) < 0.1e-3


def test_zero_vector_maps_to_straight_up():
    hrtf = load_kemar(16000)
    assert hrtf.directions[int(hrtf.nearest(np.zeros(3)))][2] == pytest.approx(1.0)


def test_missing_file_and_bad_rate(tmp_path):
    with pytest.raises(CacheError, match="libmysofa1"):
        load_kemar(16000, tmp_path / "none.sofa")
    with pytest.raises(ConfigError):
        load_kemar(0)
