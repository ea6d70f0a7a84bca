"""pi^Q's quality rewards (the ``quality_reward`` choice of PPOConfig): the step-to-step improvement of
the refined monaural estimate in one measure, plus a final-step term in the same measure."""

from __future__ import annotations

import numpy as np

from m2h_ros.core.audio.metrics import si_sdr
from m2h_ros.core.audio.stft import StftConfig, rebuild_with_phase

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


def quality_measure(name: str, estimate: np.ndarray, *, target_spec: np.ndarray, target_mag: np.ndarray,
                    target_wave: np.ndarray, config: StftConfig) -> np.ndarray:
    """(B,) quality measure ``name`` (QUALITY_REWARDS) of monaural magnitudes (B, F, T) against the target's
    dry monaural clips (B, N), their STFTs (B, F, T) and magnitudes (B, F, T). The STFTs come from the
    caller, which keeps them for the episode (the target does not change; its estimate does every step)."""
    if name == "si_sdr":
        # = stft.rebuild_ground_truth_phase(estimate, target_wave), without recomputing the target's STFT
        rebuilt = rebuild_with_phase(estimate, target_spec, config=config, length=target_wave.shape[-1])
        return si_sdr(rebuilt, target_wave)
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
