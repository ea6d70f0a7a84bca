"""Binaural direction cues: the interaural level difference (ILD) and time difference (ITD).

* :func:`interaural_level_difference`: the left/right energy ratio in dB above 1.5 kHz, where the
  head shadows the far ear (positive = louder on the left). It works from magnitudes alone, so
  also from a separator's binaural estimate.
* :func:`gcc_phat_itd`: the ITD by GCC-PHAT (Knapp & Carter 1976): the cross-spectrum of the two
  ears whitened, ``X_L X_R* / |X_L X_R*|``, summed over the STFT frames, and the lag where the
  generalised cross-correlation peaks, on a grid of fractional lags within what a head can produce
  (an 0.18 m head gives at most 0.52 ms = 8.4 samples at 16 kHz); ``lateral_sine`` maps it to
  sin(azimuth) by the free-field law ITD = d sin(azimuth) / c. Positive = the source is on the left.

Neither tells front from back (azimuths a and 180 deg - a look alike). In this simulator's rooms the
ILD is the reliable cue: ``scripts/bench/doa_cues.py`` measures both against the true bearing (the
early reflections outweigh the direct sound, which the ITD needs; see docs/design/baselines.md).
"""

from __future__ import annotations

import numpy as np

from m2h_ros.core.audio.stft import DEFAULT_STFT, StftConfig
from m2h_ros.errors import AudioError, ConfigError

ILD_MIN_HZ = 1500.0  # below this the head hardly shadows the far ear
HEAD_WIDTH = 0.18  # m, ear to ear (the acoustics' head width; the KEMAR HRIRs' ITD at 45 deg is 5% above the law)
SPEED_OF_SOUND = 343.0  # m/s
LAG_STEP = 0.25  # samples between the evaluated lags


def max_itd_samples(*, head_width: float = HEAD_WIDTH, speed_of_sound: float = SPEED_OF_SOUND,
                    sample_rate: int = DEFAULT_STFT.sample_rate) -> float:
    return head_width / speed_of_sound * sample_rate


def gcc_phat_itd(spec: np.ndarray, *, config: StftConfig = DEFAULT_STFT, max_lag: float | None = None
                 ) -> np.ndarray:
    """ITD in samples (B,) from the complex STFT (B, 2, F, T) of binaural audio (ear 0 = left, e.g.
    ``stft(audio)``).

    ``max_lag`` (samples) bounds the search; default 1.25 x the free-field maximum of an 0.18 m head
    (a real head's ITD reaches beyond the free-field law near 90 deg). Silent input gives 0.
    """
    spec = np.asarray(spec)
    if spec.ndim != 4 or spec.shape[1] != 2 or not np.iscomplexobj(spec):
        raise AudioError(f"gcc_phat_itd expects a complex binaural STFT (B, 2, F, T), got {spec.dtype} {spec.shape}")
    cross = spec[:, 0] * np.conj(spec[:, 1])
    magnitude = np.abs(cross)
    whitened = np.where(magnitude > 1e-12, cross / np.maximum(magnitude, 1e-12), 0)
    summed = whitened[:, 1:].sum(axis=-1)  # (B, F - 1): DC carries no delay
    bound = 1.25 * max_itd_samples(sample_rate=config.sample_rate) if max_lag is None else float(max_lag)
    if not bound > 0:
        raise ConfigError(f"max_lag={max_lag!r} must be > 0")
    reach = int(np.ceil(bound / LAG_STEP))
    lags = LAG_STEP * np.arange(-reach, reach + 1)
    omega = 2 * np.pi * np.arange(1, spec.shape[-2]) / config.n_fft  # rad per sample
    # X_R = X_L exp(-j w tau) for a right ear that hears tau later, so the correlation of
    # X_L X_R* with exp(-j w lag) peaks at lag = tau.
    correlation = (summed @ np.exp(-1j * np.outer(omega, lags))).real  # (B, lags)
    itd = lags[np.argmax(correlation, axis=-1)]
    return np.where(np.abs(summed).sum(axis=-1) > 0, itd, 0.0)


def lateral_sine(itd_samples: np.ndarray, *, head_width: float = HEAD_WIDTH,
                 speed_of_sound: float = SPEED_OF_SOUND, sample_rate: int = DEFAULT_STFT.sample_rate
                 ) -> np.ndarray:
    """sin(azimuth) in [-1, 1] of an ITD in samples (positive = left)."""
    limit = max_itd_samples(head_width=head_width, speed_of_sound=speed_of_sound, sample_rate=sample_rate)
    return np.clip(np.asarray(itd_samples, np.float64) / limit, -1.0, 1.0)


def interaural_level_difference(magnitude: np.ndarray, *, min_hz: float = ILD_MIN_HZ,
                                config: StftConfig = DEFAULT_STFT) -> np.ndarray:
    """ILD in dB (B,) of binaural STFT magnitudes (B, 2, F, T), ear 0 = left: 10 log10 of the left
    over the right energy in the bins at or above ``min_hz``; 0 where either ear is silent there."""
    magnitude = np.asarray(magnitude)
    if magnitude.ndim != 4 or magnitude.shape[1] != 2:
        raise AudioError(f"interaural_level_difference expects (B, 2, F, T) magnitudes, got {magnitude.shape}")
    if not np.all(np.isfinite(magnitude)):
        raise AudioError("interaural_level_difference input holds NaN or infinite values")
    first = int(np.ceil(min_hz * config.n_fft / config.sample_rate))
    energy = np.square(np.abs(magnitude[:, :, first:]), dtype=np.float64).sum(axis=(2, 3))  # (B, 2)
    audible = (energy > 1e-20).all(axis=1)
    return np.where(audible, 10 * np.log10(np.maximum(energy[:, 0], 1e-20) / np.maximum(energy[:, 1], 1e-20)), 0.0)
