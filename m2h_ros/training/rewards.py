"""pi^Q's quality rewards (the ``quality_reward`` choice of PPOConfig): the step-to-step improvement of
the refined monaural estimate in one measure, plus a final-step term in the same measure."""

from __future__ import annotations

import numpy as np

from m2h_ros.core.audio.metrics import si_sdr
from m2h_ros.core.audio.stft import StftConfig, rebuild_ground_truth_phase

# NMSE of the magnitude, SNR of the magnitude in dB, SI-SDR in dB of the ground-truth-phase rebuild
# (the evaluation's score).
QUALITY_REWARDS = ("nmse", "snr", "si_sdr")


def nmse(estimate: np.ndarray, target: np.ndarray) -> np.ndarray:
    """(B,) mean squared error of magnitudes (B, ...) over the target's mean square."""
    # float64 sums: numpy's float32 reductions round differently with the array's memory alignment,
    # which would make a resumed run (arrays loaded from a file) drift from an uninterrupted one.
    axes = tuple(range(1, target.ndim))
    error = np.mean(np.square(estimate - target), axis=axes, dtype=np.float64)
    return error / np.maximum(np.mean(np.square(target), axis=axes, dtype=np.float64), 1e-12)


def quality_measure(name: str, estimate: np.ndarray, target_mag: np.ndarray, target_wave: np.ndarray, *,
                    config: StftConfig) -> np.ndarray:
    """(B,) quality measure ``name`` (QUALITY_REWARDS) of monaural magnitudes (B, F, T) against the
    ground-truth magnitudes (B, F, T) and dry monaural clips (B, N) of the target."""
    if name == "si_sdr":
        return si_sdr(rebuild_ground_truth_phase(estimate, target_wave, config=config), target_wave)
    error = nmse(estimate, target_mag)
    return error if name == "nmse" else -10.0 * np.log10(np.maximum(error, 1e-12))


def quality_reward(name: str, before: np.ndarray, after: np.ndarray, last: np.ndarray, *,
                   final_weight: float) -> np.ndarray:
    """(B,) pi^Q's reward of a step that moved each slot's measure ``name`` from ``before`` to ``after``:
    the improvement, plus ``final_weight`` x the measure where ``last`` (B,) bool (the episode ended)."""
    sign = -1.0 if name == "nmse" else 1.0  # NMSE falls as the estimate improves, the dB measures rise
    reward = sign * (after - before)
    reward[last] += sign * final_weight * after[last]
    return reward
