"""Per-step separation scores: the one definition the evaluator node, ``scripts/evaluate.py``,
passive evaluation and offline replay scoring all use (batched, numpy).

An estimate is a monaural magnitude (..., F, T). It is rebuilt into a waveform two ways:

* ``si_sdr`` (the paper's reported variant): magnitude + the phase of the clean target, scored
  against the target's dry monaural clip. Needs the ground truth's phase: comparable with the paper,
  not something a robot can do.
* ``si_sdr_mixture_phase`` (deployable): magnitude + the phase of the mixture's ear mean, scored
  against :data:`DEPLOYABLE_REFERENCE`, the target *as heard*: the ear mean of its binaural render
  (see :func:`deployable_reference`). A robot has only the mixture's phase, and nothing it hears
  holds the dry clip's timing, colour or the room's reverberation; against the dry clip (even
  delay-aligned) the target alone as heard scores far below 0 dB, so that reference mostly measured
  the room. Against the target as heard, the mixture itself is the floor (its distractor is the
  error) and the target alone would be perfect: the number measures what separation removes.

``stft_distance`` is the original code's: the estimated magnitude with the dry target's phase against
the dry target's complex spectrogram, mean squared over real and imaginary parts
(:func:`~m2h_ros.core.audio.metrics.stft_distance`). Tables and bags of the 0.x development versions
may hold a Frobenius norm of the STFT of the ground-truth-phase rebuild minus the target's instead
(CHANGELOG.md); ``m2h-eval`` says so when it meets one.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from m2h_ros.core.audio.metrics import si_sdr, stft_distance
from m2h_ros.core.audio.stft import DEFAULT_STFT, StftConfig, rebuild_mixture_phase, rebuild_with_phase, stft
from m2h_ros.errors import AudioError

DEPLOYABLE_REFERENCE = "target as heard (ear mean)"


@dataclass(frozen=True)
class StepTruth:
    """What scoring needs of the ground truth at a step (batched over leading dims)."""

    target_monaural: np.ndarray  # (..., N) the target's dry clip
    target_binaural: np.ndarray  # (..., 2, N) the target alone as heard


@dataclass(frozen=True)
class StepScores:
    si_sdr: np.ndarray  # (...,) dB, ground-truth phase vs the dry target
    si_sdr_mixture_phase: np.ndarray  # (...,) dB, mixture phase vs the deployable reference
    stft_distance: np.ndarray  # (...,)


def deployable_reference(truth: StepTruth) -> np.ndarray:
    """The reference of the mixture-phase variant: the ear mean of the target alone as heard (..., N)."""
    binaural = np.asarray(truth.target_binaural, np.float32)
    if binaural.ndim < 2 or binaural.shape[-2] != 2:
        raise AudioError(f"target_binaural must have shape (..., 2, N), got {binaural.shape}")
    return binaural.mean(axis=-2)


def score_magnitude(magnitude: np.ndarray, mixture: np.ndarray, truth: StepTruth, *,
                    config: StftConfig = DEFAULT_STFT) -> StepScores:
    """Scores of a monaural magnitude estimate (..., F, T) given the binaural mixture (..., 2, N)."""
    magnitude = np.asarray(magnitude, np.float32)
    target = np.asarray(truth.target_monaural, np.float32)
    mixture = np.asarray(mixture, np.float32)
    if mixture.shape[:-2] != target.shape[:-1] or mixture.shape[-1] != target.shape[-1]:
        raise AudioError(f"mixture {mixture.shape} does not match target {target.shape}")
    if not np.all(np.isfinite(magnitude)):
        raise AudioError("estimate magnitude holds NaN or infinite values")
    target_spec = _target_spectrum(target, config)
    if magnitude.shape != target_spec.shape:
        raise AudioError(f"estimate magnitude {magnitude.shape} does not match the STFT of the "
                         f"target {target_spec.shape}")
    gt_phase = rebuild_with_phase(magnitude, target_spec, config=config, length=target.shape[-1])
    mixture_phase = rebuild_mixture_phase(magnitude, mixture, config=config)
    return StepScores(
        si_sdr=np.asarray(si_sdr(gt_phase, target)),
        si_sdr_mixture_phase=np.asarray(si_sdr(mixture_phase, deployable_reference(truth))),
        stft_distance=np.asarray(stft_distance(magnitude, target_spec)))


def _target_spectrum(target: np.ndarray, config: StftConfig) -> np.ndarray:
    """The STFT of the targets (..., N). A batch that repeats one clip (an episode's steps, whose target
    clip is fixed) is transformed once and broadcast: the same numbers, since each row is transformed on
    its own; a quarter of a batch's FFTs saved."""
    rows = target.reshape(-1, target.shape[-1])
    if len(rows) > 1 and bool((rows == rows[0]).all()):
        once = stft(rows[:1], config=config)
        return np.broadcast_to(once, (*target.shape[:-1], *once.shape[-2:]))
    return stft(target, config=config)
