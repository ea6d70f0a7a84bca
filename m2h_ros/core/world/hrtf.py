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

Other heads (``load_head``; the ``head`` setting of the acoustics): ``kemar`` (the above),
``sofa:PATH`` (any head or array measured as a SOFA file with two receivers, read with sofar, resampled
from a rate at or above the simulation's) or ``free_field:SPACING_M`` (two omnidirectional microphones
SPACING_M apart on the left-right axis, no head between them: each ear is a band-limited fractional delay
of the plane wave, so ITD = spacing * sin(azimuth) / c and ILD = 0). Every head goes through the same
diffuse-field equalisation and normalisation. Directions of a SOFA head or a free-field pair are weighted
by the solid angle nearest to each (a dense uniform sampling of the sphere assigned to its nearest
direction, which is how the simulation picks a direction), as KEMAR's rings are.
"""

from __future__ import annotations

import functools
import hashlib
from dataclasses import dataclass
from pathlib import Path

import h5py
import numpy as np

from m2h_ros.core.sounds.sources import sources_dir
from m2h_ros.errors import CacheError, ConfigError, HeadError

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
    # m: distance between the two ears where the head defines it (free-field pair, SOFA receiver
    # positions); None: the acoustics' head_width stands for it (KEMAR)
    ear_spacing: float | None = None

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


def _prepared(hrirs: np.ndarray, directions: np.ndarray, weights: np.ndarray, centre: float, file_rate: int,
              sample_rate: int, *, equalise: bool, ear_spacing: float | None = None) -> Hrtf:
    """An Hrtf from raw (D, 2, L) HRIRs at ``file_rate`` whose head-centre arrival is sample ``centre``:
    onsets trimmed, resampled, diffuse-field equalised (unless ``equalise`` is False) and normalised to
    unit diffuse-field energy per ear."""
    from scipy.signal import fftconvolve, resample_poly  # here: most processes never load a head

    trim = max(0, int(_first_onset(hrirs).min()) - _ONSET_MARGIN * file_rate // sample_rate)
    hrirs = hrirs[..., trim:]
    centre -= trim

    divisor = np.gcd(sample_rate, file_rate)
    resampled = resample_poly(hrirs, sample_rate // divisor, file_rate // divisor, axis=-1)
    if equalise:
        # Minimum phase: the filter's energy sits at its start, so onsets (and ITD) barely move.
        resampled = fftconvolve(resampled, _equaliser(resampled, weights, sample_rate)[None, None], axes=-1)
    energy = np.einsum("d,de->", weights, (resampled**2).sum(axis=-1)) / 2  # per ear, diffuse field
    resampled /= np.sqrt(energy)
    return Hrtf(
        sample_rate=sample_rate,
        directions=directions,
        hrirs=resampled.astype(np.float32),
        centre_delay=centre * sample_rate / file_rate,
        weights=weights,
        ear_spacing=ear_spacing,
    )


def _unit_vectors(azimuth_deg: np.ndarray, elevation_deg: np.ndarray) -> np.ndarray:
    az, el = np.deg2rad(azimuth_deg), np.deg2rad(elevation_deg)
    return np.stack([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)], axis=-1)


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
    return _prepared(hrirs, _unit_vectors(az_el[:, 0], az_el[:, 1]), _solid_angle_weights(az_el[:, 1]),
                     centre, file_rate, sample_rate, equalise=equalise)


# ----------------------------------------------------------------------------- other heads

KEMAR = "kemar"
HEAD_HELP = ("the head the ears are simulated with: kemar (default), sofa:PATH (a SOFA HRIR file with two "
             "receivers) or free_field:SPACING_M (two microphones SPACING_M apart, no head)")
SPEED_OF_SOUND = 343.0  # m/s: the free-field pair's delays (the acoustics' default)
MIN_SPACING, MAX_SPACING = 0.01, 1.0  # m: a free-field pair's spacing
FREE_FIELD_DIRECTIONS = 710  # as many as KEMAR measures
_FREE_FIELD_HALF = 32  # taps each side of the fractional-delay kernel's centre
_WEIGHT_SAMPLES = 40_000  # uniform sphere samples that share out the solid angle


@dataclass(frozen=True)
class Head:
    """A parsed ``head`` setting: ``kemar``, ``sofa:PATH`` or ``free_field:SPACING_M``."""

    kind: str  # "kemar", "sofa" or "free_field"
    path: Path | None = None
    spacing: float | None = None


def parse_head(spec: str) -> Head:
    """The head a setting names (the file is not read here; ConfigError for a malformed setting)."""
    if not isinstance(spec, str):
        raise ConfigError(f"head must be a string (kemar, sofa:PATH or free_field:SPACING_M), got {spec!r}")
    kind, _, rest = spec.partition(":")
    if spec == KEMAR:
        return Head(KEMAR)
    if kind == "sofa" and rest:
        return Head("sofa", path=Path(rest).expanduser())
    if kind == "free_field" and rest:
        try:
            spacing = float(rest)
        except ValueError:
            spacing = float("nan")
        if not MIN_SPACING <= spacing <= MAX_SPACING:
            raise ConfigError(f"head {spec!r}: the free-field spacing must be a number of metres in "
                              f"[{MIN_SPACING}, {MAX_SPACING}]")
        return Head("free_field", spacing=spacing)
    raise ConfigError(f"head {spec!r} is not one of: kemar, sofa:PATH (a SOFA HRIR file), "
                      f"free_field:SPACING_M (two microphones, no head)")


@functools.lru_cache(maxsize=32)
def _file_digest(path: Path, size: int, mtime_ns: int) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()[:16]


def head_identity(spec: str) -> str | None:
    """What keys a head's acoustics: None for KEMAR (its banks keep the digest they always had), the
    SOFA file's content digest (not its path: a copied file keeps its banks), the pair's spacing."""
    head = parse_head(spec)
    if head.kind == KEMAR:
        return None
    if head.kind == "free_field":
        return f"free_field {head.spacing!r} m"
    if not head.path.is_file():
        raise HeadError(f"head file {head.path} does not exist")
    stat = head.path.stat()
    return f"sofa sha256:{_file_digest(head.path.resolve(), stat.st_size, stat.st_mtime_ns)}"


def nearest_share_weights(directions: np.ndarray) -> np.ndarray:
    """(D,) solid-angle weights of arbitrary unit ``directions``: the share of a dense uniform sphere
    sampling whose nearest direction each one is (a direction that is nobody's nearest gets 0)."""
    from pyroomacoustics.doa import fibonacci_spherical_sampling

    dense = fibonacci_spherical_sampling(_WEIGHT_SAMPLES).T
    counts = np.zeros(len(directions))
    for chunk in np.array_split(dense, 20):
        np.add.at(counts, np.argmax(chunk @ directions.T, axis=-1), 1)
    return counts / counts.sum()


def _free_field(spacing: float, sample_rate: int, *, equalise: bool) -> Hrtf:
    """Two omnidirectional microphones at +-spacing/2 on the left-right axis (left = +y): every
    direction's plane wave reaches each one ``position . direction / c`` before the centre; each ear is
    that delay as a Hann-windowed sinc (band limited, the same magnitude at both ears: ILD 0)."""
    from pyroomacoustics.doa import fibonacci_spherical_sampling

    directions = fibonacci_spherical_sampling(FREE_FIELD_DIRECTIONS).T.astype(np.float64)
    ears = np.array([[0.0, spacing / 2, 0.0], [0.0, -spacing / 2, 0.0]])
    lead = directions @ ears.T / SPEED_OF_SOUND * sample_rate  # (D, 2) samples before the centre
    taps = np.arange(2 * _FREE_FIELD_HALF + 1)
    delay = _FREE_FIELD_HALF - lead
    hrirs = np.sinc(taps - delay[..., None]) * np.hanning(len(taps))
    return _prepared(hrirs, directions, nearest_share_weights(directions), float(_FREE_FIELD_HALF),
                     sample_rate, sample_rate, equalise=equalise, ear_spacing=spacing)


def _sofa_directions(path: Path, sofa, count: int) -> np.ndarray:
    """(count, 3) unit vectors of a SOFA file's SourcePosition (spherical degrees or cartesian)."""
    positions = np.asarray(getattr(sofa, "SourcePosition", np.zeros((0, 3))), dtype=np.float64)
    kind = str(getattr(sofa, "SourcePosition_Type", "spherical")).lower()
    if positions.ndim != 2 or positions.shape[1] != 3 or len(positions) != count:
        raise HeadError(f"head file {path}: SourcePosition has shape {positions.shape}, expected ({count}, 3), "
                        f"one position per impulse response")
    if not np.isfinite(positions).all():
        raise HeadError(f"head file {path}: SourcePosition holds NaN or infinite values")
    if kind.startswith("cartesian"):
        norms = np.linalg.norm(positions, axis=-1)
        if not (norms > 0).all():
            raise HeadError(f"head file {path}: {int((norms <= 0).sum())} source positions are at the head's "
                            f"centre (no direction)")
        directions = positions / norms[:, None]
    elif kind.startswith("spherical"):
        elevation = positions[:, 1]
        if (np.abs(elevation) > 90).any():
            raise HeadError(f"head file {path}: elevations outside [-90, 90] degrees "
                            f"(e.g. {elevation[np.abs(elevation) > 90][0]:g})")
        directions = _unit_vectors(positions[:, 0], elevation)
    else:
        raise HeadError(f"head file {path}: SourcePosition_Type {kind!r} is neither spherical nor cartesian")
    if len(np.unique(np.round(directions, 6), axis=0)) < 2:
        raise HeadError(f"head file {path}: every impulse response is at the same direction")
    return directions


def _ear_spacing(sofa) -> float | None:
    """Distance between the two receivers where the file gives them as cartesian metres."""
    positions = np.asarray(getattr(sofa, "ReceiverPosition", np.zeros(0)), dtype=np.float64)
    if str(getattr(sofa, "ReceiverPosition_Type", "")).lower() != "cartesian" or positions.shape[:2] != (2, 3):
        return None
    spacing = float(np.linalg.norm(positions[0, :, 0] - positions[1, :, 0]))
    return spacing if MIN_SPACING <= spacing <= MAX_SPACING else None


def _sofa_head(path: Path, sample_rate: int, *, equalise: bool) -> Hrtf:
    """A head measured as a SOFA HRIR file, checked: every way it can be unusable is a HeadError."""
    import sofar  # only SOFA heads need it

    if not path.is_file():
        raise HeadError(f"head file {path} does not exist")
    try:
        sofa = sofar.read_sofa(str(path), verify=False, verbose=False)
    except Exception as err:  # noqa: BLE001 - netCDF, HDF5 and sofar raise many types for a bad file
        raise HeadError(f"head file {path} is unreadable as SOFA: {type(err).__name__}: {err}") from err
    if getattr(sofa, "Data_IR", None) is None:
        raise HeadError(f"head file {path} holds no impulse responses (Data.IR; convention "
                        f"{getattr(sofa, 'GLOBAL_SOFAConventions', '?')}): a head needs an HRIR set")
    hrirs = np.asarray(sofa.Data_IR, dtype=np.float64)
    if hrirs.ndim != 3 or hrirs.size == 0:
        raise HeadError(f"head file {path} holds no impulse responses (Data.IR has shape {hrirs.shape})")
    if hrirs.shape[1] != 2:
        raise HeadError(f"head file {path} has {hrirs.shape[1]} receivers; a binaural head needs 2 "
                        f"(receiver 0 = left ear, 1 = right)")
    if not np.isfinite(hrirs).all():
        bad = int((~np.isfinite(hrirs)).any(axis=(1, 2)).sum())
        raise HeadError(f"head file {path}: {bad} of {len(hrirs)} impulse responses hold NaN or infinite samples")
    silent = ~hrirs.any(axis=-1)  # (D, 2)
    if silent.any():
        ears = [name for name, column in zip(("left", "right"), silent.T) if column.any()]
        raise HeadError(f"head file {path}: {int(silent.any(axis=1).sum())} of {len(hrirs)} directions have "
                        f"an all-zero impulse response ({' and '.join(ears)} ear)")
    rate = np.asarray(getattr(sofa, "Data_SamplingRate", np.nan), dtype=np.float64).ravel()
    file_rate = int(round(float(rate[0]))) if rate.size and np.isfinite(rate[0]) else 0
    if file_rate < sample_rate:
        raise HeadError(f"head file {path} is sampled at {file_rate} Hz, below the simulation's {sample_rate} Hz "
                        f"(higher rates are resampled; lower ones lack the upper band)")
    directions = _sofa_directions(path, sofa, len(hrirs))
    front = int(np.argmax(directions @ np.array([1.0, 0.0, 0.0])))
    centre = float(_first_onset(hrirs[front]).mean())  # frontal arrival ~ head-centre arrival
    return _prepared(hrirs, directions, nearest_share_weights(directions), centre, file_rate, sample_rate,
                     equalise=equalise, ear_spacing=_ear_spacing(sofa))


@functools.lru_cache(maxsize=8)
def _cached_head(spec: str, identity: str | None, sample_rate: int, equalise: bool) -> Hrtf:
    head = parse_head(spec)
    if head.kind == KEMAR:
        return load_kemar(sample_rate, equalise=equalise)
    if head.kind == "free_field":
        return _free_field(head.spacing, sample_rate, equalise=equalise)
    return _sofa_head(head.path, sample_rate, equalise=equalise)


def load_head(spec: str = KEMAR, sample_rate: int = 16000, *, equalise: bool = True) -> Hrtf:
    """The Hrtf of a ``head`` setting (cached per content: an edited SOFA file is read again)."""
    if sample_rate <= 0:
        raise ConfigError(f"sample_rate must be positive, got {sample_rate}")
    return _cached_head(spec, head_identity(spec), sample_rate, equalise)
