"""pi^Q's quality rewards (the ``quality_reward`` choice of PPOConfig): the step-to-step improvement of
the refined monaural estimate in one measure, plus a final-step term in the same measure."""

from __future__ import annotations

from collections.abc import Callable
from concurrent.futures import Future, ThreadPoolExecutor
from functools import partial
from typing import Any

import numpy as np

from m2h_ros.core.audio.metrics import si_sdr
from m2h_ros.core.audio.stft import StftConfig, rebuild_with_phase, stft

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


class PendingQuality:
    """A step's measures (after the step, its NMSE, the new episodes' first), computed on the tracker's
    worker from ``start()`` (the trainer starts it where its own thread leaves a core free), or on
    ``result()``."""

    def __init__(self, job: Callable[[], tuple[np.ndarray, np.ndarray, np.ndarray]], ended: np.ndarray,
                 worker: ThreadPoolExecutor | None) -> None:
        self.ended, self._job, self._worker = ended, job, worker
        self._measures: Future | None = None

    def start(self) -> None:
        if self._measures is None:
            if self._worker is not None:
                self._measures = self._worker.submit(self._job)
            else:
                self._measures = Future()
                self._measures.set_result(self._job())

    def result(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        self.start()
        return self._measures.result()


class QualityTracker:
    """pi^Q's reward state of B slots: each slot's target (dry clip ``wave``, its STFT ``spec`` and magnitude
    ``mag``, kept for the episode: the target does not change, its estimate does every step), the measure of
    its current estimate (``measure_now``) and, from the last settled step, the measure and NMSE that ended
    an episode (``final_quality``, ``final_nmse``).

    ``submit`` starts a step's measures on a worker thread and ``settle``, called in step order, makes them
    that step's reward, so the trainer acts, steps the environment and separates meanwhile (numpy and
    pocketfft release the GIL). The numbers are those computed in line (``threaded=False``): a pending step
    reads only arrays that are never written again, since a new episode's target replaces the arrays.
    """

    def __init__(self, name: str, *, final_weight: float, config: StftConfig, threaded: bool) -> None:
        self.name, self.final_weight, self.config = name, final_weight, config
        self._worker = ThreadPoolExecutor(max_workers=1, thread_name_prefix="reward") if threaded else None

    def start(self, target_wave: np.ndarray, estimate: np.ndarray) -> None:
        """Every slot begins an episode with target clips (B, N) and first refined estimates (B, F, T)."""
        self.wave = np.array(target_wave)
        self.spec = stft(self.wave, config=self.config)
        self.mag = np.abs(self.spec)
        self.measure_now = self._measure(estimate, (self.spec, self.mag, self.wave))
        self.final_nmse, self.final_quality = np.zeros(len(self.wave)), np.zeros(len(self.wave))

    def state(self) -> dict[str, np.ndarray]:
        return {"target_wave": self.wave, "measure_now": self.measure_now, "final_nmse": self.final_nmse,
                "final_quality": self.final_quality}

    def restore(self, state: dict[str, Any]) -> None:
        self.wave = np.array(state["target_wave"])
        self.spec = stft(self.wave, config=self.config)
        self.mag = np.abs(self.spec)
        self.measure_now, self.final_nmse, self.final_quality = (
            np.array(state[key]) for key in ("measure_now", "final_nmse", "final_quality"))

    def submit(self, estimate: np.ndarray, ended: np.ndarray, fresh_estimate: np.ndarray,
               fresh_wave: np.ndarray) -> PendingQuality:
        """A step taken: ``estimate`` (B, F, T) every slot's refined estimate after it (an ended episode's
        last), ``ended`` (E,) the slots whose episode it ended, ``fresh_estimate`` (E, F, T) and
        ``fresh_wave`` (E, N) their next episode's first estimate and target clip."""
        before = (self.spec, self.mag, self.wave)
        if len(ended):
            self.wave, self.spec, self.mag = self.wave.copy(), self.spec.copy(), self.mag.copy()
            self.wave[ended] = fresh_wave
            self.spec[ended] = stft(self.wave[ended], config=self.config)
            self.mag[ended] = np.abs(self.spec[ended])
        fresh = (self.spec[ended], self.mag[ended], self.wave[ended])
        return PendingQuality(partial(self._step, estimate, before, fresh_estimate, fresh), ended, self._worker)

    def settle(self, pending: PendingQuality) -> np.ndarray:
        """(B,) the reward of the oldest unsettled step (``pending``), which becomes the current state."""
        after, final_nmse, fresh = pending.result()
        last = np.zeros(len(after), bool)
        last[pending.ended] = True
        reward = quality_reward(self.name, self.measure_now, after, last, final_weight=self.final_weight)
        self.final_quality, self.final_nmse = after, final_nmse
        # Slots that go on keep their estimate and target: only the new episodes' measure is new.
        self.measure_now = after.copy()
        self.measure_now[pending.ended] = fresh
        return reward

    def _step(self, estimate: np.ndarray, targets: tuple[np.ndarray, ...], fresh_estimate: np.ndarray,
              fresh_targets: tuple[np.ndarray, ...]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        after = self._measure(estimate, targets)
        final_nmse = after if self.name == "nmse" else nmse(estimate, targets[1])
        fresh = self._measure(fresh_estimate, fresh_targets) if len(fresh_estimate) else np.zeros(0)
        return after, final_nmse, fresh

    def _measure(self, estimate: np.ndarray, targets: tuple[np.ndarray, ...]) -> np.ndarray:
        spec, mag, wave = targets
        return quality_measure(self.name, estimate, target_spec=spec, target_mag=mag, target_wave=wave,
                               config=self.config)
