"""Measured head-related impulse responses (MIT KEMAR, normal pinna) for binaural rendering.

The SOFA file comes from the Debian package ``libmysofa1`` (MIT Media Lab measurements, free to use
with citation: Gardner & Martin, "HRTF measurements of a KEMAR dummy-head microphone", 1994).
It holds 710 directions at 44.1 kHz, 512 taps; we read it with h5py and resample to the simulation
rate. Head frame: x to the front, y to the left, z up; SOFA azimuth is counter-clockwise from the
front (90 deg = left) and its receiver 0 is the left ear, so ear index 0 = left, 1 = right.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass
from pathlib import Path

import h5py
import numpy as np
from scipy.signal import resample_poly

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


@dataclass(frozen=True)
class Hrtf:
    """HRIRs on a direction grid, aligned so that sample ``centre_delay`` is the head-centre time."""

    sample_rate: int
    directions: np.ndarray  # (D, 3) unit vectors in the head frame
    hrirs: np.ndarray  # (D, 2, L) float32, ears (left, right)
    centre_delay: float  # samples: arrival time at the head centre inside every HRIR

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


@functools.lru_cache(maxsize=4)
def load_kemar(sample_rate: int = 16000, path: Path | None = None) -> Hrtf:
    """Read the KEMAR SOFA file, resample it and normalise it to unit diffuse-field energy per ear."""
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
    energy = (resampled**2).sum(axis=-1).mean()  # mean over directions and ears
    resampled /= np.sqrt(energy)

    az, el = np.deg2rad(az_el[:, 0]), np.deg2rad(az_el[:, 1])
    directions = np.stack([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)], axis=-1)
    return Hrtf(
        sample_rate=sample_rate,
        directions=directions,
        hrirs=resampled.astype(np.float32),
        centre_delay=centre * sample_rate / file_rate,
    )
