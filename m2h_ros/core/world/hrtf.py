"""Measured head-related impulse responses (MIT KEMAR, normal pinna) for binaural rendering.

The SOFA file comes from the Debian package ``libmysofa1`` (MIT Media Lab measurements, free to use
with citation: Gardner & Martin, "HRTF measurements of a KEMAR dummy-head microphone", 1994).
It holds 710 directions at 44.1 kHz, 512 taps; we read it with h5py and resample to the simulation
rate. Head frame: x to the front, y to the left, z up; SOFA azimuth is counter-clockwise from the
front (90 deg = left) and its receiver 0 is the left ear, so ear index 0 = left, 1 = right.

Diffuse-field equalisation (``equalise=True``, the default): the raw set is 12-19 dB weaker below
1 kHz than at 2-4 kHz (the ear canal resonance and the measurement chain), while the room's diffuse
tail is white. We weight every measured direction by the solid angle of its elevation ring (the
grid is denser at the poles per unit area than a uniform one would be), take the power average over
directions and both ears, smooth it over 1/3 octave, and divide every HRIR by its square root with
one minimum-phase filter. The filter's gain is band limited (held constant below EQ_BAND[0] and
above EQ_BAND[1], where the measurement says little) and regularised (clipped to EQ_MAX_DB around
its median), and its impulse response is cut to EQ_TAPS with a half-Hann fade. The same filter on
both ears of every direction leaves ITD and ILD as measured.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass
from pathlib import Path

import h5py
import numpy as np
from scipy.signal import fftconvolve, resample_poly

from m2h_ros.core.sounds.sources import sources_dir
from m2h_ros.errors import CacheError, ConfigError

HRTF_PACKAGE = ("libmysofa1", "1.3.1~dfsg0-1")  # fetched by scripts/fetch_sound_sources.sh
_KEMAR_IN_PACKAGE = "usr/share/libmysofa/MIT_KEMAR_normal_pinna.sofa"


def kemar_sofa_path() -> Path:
    """The KEMAR SOFA file: the installed libmysofa1 package's, else the one that
    scripts/fetch_sound_sources.sh unpacks (no root needed)."""
    system = Path("/") / _KEMAR_IN_PACKAGE
    return system if system.is_file() else sources_dir() / "root" / _KEMAR_IN_PACKAGE

# Samples kept before the earliest ear onset over all directions (room for the resampling filter).
_ONSET_MARGIN = 2
EQ_BAND = (150.0, 7000.0)  # Hz: the equaliser's gain is held constant outside this band
EQ_MAX_DB = 20.0  # the equaliser's gain stays within +-EQ_MAX_DB of its median
EQ_TAPS = 128  # length of the minimum-phase equaliser
_EQ_FFT = 1024


@dataclass(frozen=True)
class Hrtf:
    """HRIRs on a direction grid, aligned so that sample ``centre_delay`` is the head-centre time."""

    sample_rate: int
    directions: np.ndarray  # (D, 3) unit vectors in the head frame
    hrirs: np.ndarray  # (D, 2, L) float32, ears (left, right)
    centre_delay: float  # samples: arrival time at the head centre inside every HRIR
    weights: np.ndarray  # (D,) solid-angle share of every direction, summing to 1

    def nearest(self, vectors: np.ndarray) -> np.ndarray:
        """Index of the measured direction closest to each (.., 3) head-frame vector."""
        norms = np.linalg.norm(vectors, axis=-1, keepdims=True)
        # A zero vector (source at the head centre) has no direction: use straight up,
        # which is the same for both ears and for every heading.
        unit = np.where(norms > 1e-9, vectors / np.maximum(norms, 1e-12), np.array([0.0, 0.0, 1.0]))
        return np.argmax(unit @ self.directions.T, axis=-1)


def _first_onset(ir: np.ndarray, threshold: float = 0.2) -> np.ndarray:
    """First sample where |ir| reaches ``threshold`` times its peak, along the last axis."""
    peak = np.abs(ir).max(axis=-1, keepdims=True)
    return np.argmax(np.abs(ir) >= threshold * peak, axis=-1)


def _solid_angle_weights(elevation_deg: np.ndarray) -> np.ndarray:
    """(D,) weights of directions on elevation rings: each ring's solid angle (between the midpoints
    to its neighbour rings, the lowest ring as wide below as above) shared by its directions."""
    rings, inverse, counts = np.unique(np.round(elevation_deg, 3), return_inverse=True, return_counts=True)
    edges = np.concatenate([[rings[0] - (rings[1] - rings[0]) / 2], (rings[1:] + rings[:-1]) / 2, [90.0]])
    band = np.diff(np.sin(np.deg2rad(np.clip(edges, -90, 90))))
    weights = (band / counts)[inverse]
    return weights / weights.sum()


def diffuse_field_power(hrirs: np.ndarray, weights: np.ndarray, n_fft: int) -> np.ndarray:
    """(n_fft // 2 + 1,) solid-angle weighted power average over directions and both ears."""
    power = np.abs(np.fft.rfft(np.asarray(hrirs, np.float64), n_fft, axis=-1)) ** 2
    return np.einsum("d,def->f", weights, power) / hrirs.shape[1]


def third_octave_smooth(values: np.ndarray, freqs: np.ndarray) -> np.ndarray:
    """Mean of ``values`` over the 1/3 octave around each frequency (DC keeps its own value)."""
    out = np.array(values, dtype=np.float64)
    for i, f in enumerate(freqs):
        if f > 0:
            out[i] = values[(freqs >= f * 2 ** (-1 / 6)) & (freqs <= f * 2 ** (1 / 6))].mean()
    return out


def _minimum_phase(magnitude: np.ndarray, n_fft: int) -> np.ndarray:
    """(n_fft,) minimum-phase impulse response of an rfft magnitude (real-cepstrum folding)."""
    cepstrum = np.fft.irfft(np.log(magnitude), n_fft)
    fold = np.zeros(n_fft)
    fold[0], fold[n_fft // 2] = 1.0, 1.0
    fold[1: n_fft // 2] = 2.0
    return np.fft.irfft(np.exp(np.fft.rfft(cepstrum * fold, n_fft)), n_fft)


def _equaliser(hrirs: np.ndarray, weights: np.ndarray, sample_rate: int) -> np.ndarray:
    """(EQ_TAPS,) minimum-phase diffuse-field inverse filter (see the module docstring)."""
    freqs = np.fft.rfftfreq(_EQ_FFT, 1.0 / sample_rate)
    power = third_octave_smooth(diffuse_field_power(hrirs, weights, _EQ_FFT), freqs)
    inside = (freqs >= EQ_BAND[0]) & (freqs <= min(EQ_BAND[1], 0.45 * sample_rate))
    gain_db = -10 * np.log10(np.interp(freqs, freqs[inside], power[inside]))  # held outside the band
    median = np.median(gain_db[inside])
    gain_db = np.clip(gain_db, median - EQ_MAX_DB, median + EQ_MAX_DB)
    taps = _minimum_phase(10 ** (gain_db / 20), _EQ_FFT)[:EQ_TAPS]
    fade = EQ_TAPS // 4
    taps[-fade:] *= np.hanning(2 * fade)[fade:]
    return taps


@functools.lru_cache(maxsize=8)
def load_kemar(sample_rate: int = 16000, path: Path | None = None, *, equalise: bool = True) -> Hrtf:
    """Read the KEMAR SOFA file, resample it, diffuse-field equalise it (unless ``equalise`` is
    False) and normalise it to unit diffuse-field energy per ear."""
    if sample_rate <= 0:
        raise ConfigError(f"sample_rate must be positive, got {sample_rate}")
    path = Path(path) if path is not None else kemar_sofa_path()
    if not path.is_file():
        raise CacheError(f"HRTF file {path} is missing: run scripts/setup.sh (it fetches the Debian "
                         f"package libmysofa1) or install libmysofa1")
    try:
        with h5py.File(path, "r") as sofa:
            file_rate = int(round(float(sofa["Data.SamplingRate"][0])))
            hrirs = np.asarray(sofa["Data.IR"][:], dtype=np.float64)
            az_el = np.asarray(sofa["SourcePosition"][:, :2], dtype=np.float64)
    except (OSError, KeyError) as err:
        raise CacheError(f"HRTF file {path} is unreadable as SOFA: {err}") from err

    front = int(np.argmin(np.abs(az_el[:, 0]) + np.abs(az_el[:, 1])))
    centre = float(_first_onset(hrirs[front]).mean())  # frontal arrival ~ head-centre arrival
    trim = max(0, int(_first_onset(hrirs).min()) - _ONSET_MARGIN * file_rate // sample_rate)
    hrirs = hrirs[..., trim:]
    centre -= trim

    divisor = np.gcd(sample_rate, file_rate)
    resampled = resample_poly(hrirs, sample_rate // divisor, file_rate // divisor, axis=-1)
    weights = _solid_angle_weights(az_el[:, 1])
    if equalise:
        # Minimum phase: the filter's energy sits at its start, so onsets (and ITD) barely move.
        resampled = fftconvolve(resampled, _equaliser(resampled, weights, sample_rate)[None, None], axes=-1)
    energy = np.einsum("d,de->", weights, (resampled**2).sum(axis=-1)) / 2  # per ear, diffuse field
    resampled /= np.sqrt(energy)

    az, el = np.deg2rad(az_el[:, 0]), np.deg2rad(az_el[:, 1])
    directions = np.stack([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)], axis=-1)
    return Hrtf(
        sample_rate=sample_rate,
        directions=directions,
        hrirs=resampled.astype(np.float32),
        centre_delay=centre * sample_rate / file_rate,
        weights=weights,
    )
