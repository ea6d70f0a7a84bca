"""Separation metrics shared by training, the evaluator node and offline scoring (numpy, batched).

* :func:`si_sdr` - scale-invariant signal-to-distortion ratio in dB, zero-mean (as nussl, which the
  paper used; a DC offset of 0.05 moves unmeaned results by up to 17 dB). Same formula as torchmetrics
  ``scale_invariant_signal_distortion_ratio(zero_mean=True)``.
* :func:`stft_distance` - the original code's STFT distance (``STFT_L2_distance``, monaural): the
  estimated magnitude with the reference's phase against the reference's complex spectrogram, the
  mean squared difference over the real and imaginary parts of every bin (what produced the paper's
  figures; the paper's text calls it a Euclidean distance).
* :func:`delayed` - a reference shifted later by whole samples (zeros in front), to score estimates in
  the mixture's phase against the dry clip as the microphones hear it in time (delay-aligned).
"""

from __future__ import annotations

import numpy as np

from m2h_ros.errors import AudioError

# A reference whose (zero-mean) energy per sample is below this is treated as silent: SI-SDR would
# project the estimate onto noise-free nothing and the ratio is undefined.
SILENT_ENERGY_PER_SAMPLE = 1e-12


def all_finite(x: np.ndarray) -> bool:
    """``np.all(np.isfinite(x))``; a complex array is checked as its real and imaginary floats, which
    numpy does several times faster than complex ``isfinite`` (same answer: both parts finite)."""
    x = np.asarray(x)
    if not np.iscomplexobj(x):
        return bool(np.all(np.isfinite(x)))
    parts = (x.reshape(-1).view(x.real.dtype),) if x.flags.c_contiguous else (x.real, x.imag)
    return all(bool(np.all(np.isfinite(part))) for part in parts)


def _finite(x: np.ndarray, name: str) -> np.ndarray:
    x = np.asarray(x)
    if not all_finite(x):
        raise AudioError(f"{name} holds NaN or infinite values")
    return x


def si_sdr(estimate: np.ndarray, reference: np.ndarray) -> np.ndarray | float:
    """SI-SDR in dB of ``estimate`` against ``reference``, both (..., N); returns shape (...).

    Both signals are made zero-mean, the reference is scaled by the optimal
    alpha = <est, ref> / <ref, ref>, and SI-SDR = 10 log10(|alpha ref|^2 / |est - alpha ref|^2).
    Computed in float64. Raises AudioError for NaN/inf input, mismatched shapes, or a silent reference
    (zero-mean energy below ``SILENT_ENERGY_PER_SAMPLE`` per sample), for which SI-SDR is undefined.
    A perfect estimate gives a large finite value (the error energy is floored at float64 eps).
    """
    est = _finite(estimate, "SI-SDR estimate").astype(np.float64)
    ref = _finite(reference, "SI-SDR reference").astype(np.float64)
    if est.shape != ref.shape or est.ndim < 1:
        raise AudioError(f"SI-SDR needs equal shapes (..., N), got {est.shape} and {ref.shape}")
    # In place on the float64 copies, products into one scratch array: the same numbers as the plain
    # expressions (numpy's pairwise sums, row by row, so batching changes nothing) at half the memory
    # traffic.
    est -= est.mean(axis=-1, keepdims=True)
    ref -= ref.mean(axis=-1, keepdims=True)
    scratch = np.empty_like(ref)

    def dot(a: np.ndarray, b: np.ndarray) -> np.ndarray:
        return np.multiply(a, b, out=scratch).sum(axis=-1, keepdims=True)

    ref_energy = dot(ref, ref)
    if np.any(ref_energy <= SILENT_ENERGY_PER_SAMPLE * ref.shape[-1]):
        raise AudioError("SI-SDR reference is silent (zero-mean energy ~0): the ratio is undefined")
    target = dot(est, ref) / ref_energy * ref
    noise = np.subtract(est, target, out=est)
    eps = np.finfo(np.float64).eps
    ratio = (dot(target, target)[..., 0] + eps) / (dot(noise, noise)[..., 0] + eps)
    result = 10.0 * np.log10(ratio)
    return float(result) if result.ndim == 0 else result


def stft_distance(magnitude: np.ndarray, reference_spec: np.ndarray) -> np.ndarray | float:
    """STFT distance of an estimated magnitude (..., F, T) from a reference complex spectrogram
    (..., F, T) -> (...), as the original code computes it: the estimate takes the reference's phase,
    both are split into real and imaginary parts, and the distance is the mean squared difference
    over those 2 F T numbers. With the phase shared that is sum((|est| - |ref|)^2) / (2 F T), which
    is how it is computed here (float64; no trigonometry, no inverse STFT)."""
    est = _finite(magnitude, "STFT-distance estimate")
    ref = _finite(reference_spec, "STFT-distance reference")
    if est.shape != ref.shape or est.ndim < 2:
        raise AudioError(f"STFT distance needs equal shapes (..., F, T), got {est.shape} and {ref.shape}")
    if np.iscomplexobj(est) or np.any(est < 0):
        raise AudioError("STFT-distance estimate must be a magnitude (real, >= 0)")
    diff = est.astype(np.float64) - np.abs(ref).astype(np.float64)
    result = 0.5 * np.mean(np.square(diff), axis=(-2, -1))
    return float(result) if result.ndim == 0 else result


def delayed(reference: np.ndarray, samples: int | np.ndarray) -> np.ndarray:
    """``reference`` (..., N) delayed by ``samples`` whole samples (an int, or one per leading index,
    broadcast against shape (...)): zeros fill the start and the end is cut, so the length stays N.

    The delay-aligned reference of a reverberant recording: the ears hear the dry clip after the
    direct path's propagation delay, so scoring a mixture-phase estimate against the undelayed clip
    measures the misalignment, not the separation. Negative or non-integer delays raise AudioError.
    """
    ref = np.asarray(reference)
    shift = np.asarray(samples)
    if ref.ndim < 1:
        raise AudioError(f"delayed needs a reference of shape (..., N), got {ref.shape}")
    if not np.issubdtype(shift.dtype, np.integer) or np.any(shift < 0):
        raise AudioError(f"delays must be non-negative whole samples, got {samples!r}")
    n = ref.shape[-1]
    index = np.arange(n) - shift[..., None]  # (..., N): source sample of each output sample
    index, ref = np.broadcast_arrays(index, ref)
    out = np.take_along_axis(ref, np.clip(index, 0, n - 1), axis=-1)
    return np.where(index >= 0, out, np.zeros((), ref.dtype))
