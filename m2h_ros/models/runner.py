"""The passive separator run step by step over episode slots: what the separator node (one slot) and
in-process evaluation (many) both call, so a ROS run and an in-process run compute the same numbers.

Each slot keeps its f^R memory; ``step(..., reset=...)`` starts a slot afresh (a new episode).
Outputs are numpy arrays in the (F, T) layout, linear magnitudes.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch

from m2h_ros.core.audio.stft import from_slices, rebuild_mixture_phase, stft
from m2h_ros.errors import AudioError, ConfigError
from m2h_ros.models.checkpoint import LoadedSeparator
from m2h_ros.models.inference import fuse_for_inference
from m2h_ros.models.separator import N_EARS, network_input


@dataclass(frozen=True)
class SeparationStep:
    """One step's separator outputs for B slots (float32)."""

    binaural: np.ndarray  # (B, 2, F, T) f^B: the target as heard, linear magnitude
    monaural: np.ndarray  # (B, F, T) f^M
    refined: np.ndarray  # (B, F, T) f^R (the memory carried to the next step)

    def waveform(self, mixture: np.ndarray, *, config) -> np.ndarray:
        """(B, N) the refined estimate rebuilt with the mixture's phase (what a listener hears)."""
        return rebuild_mixture_phase(self.refined, mixture, config=config)


class SeparatorRunner:
    """f^B -> f^M -> f^R over ``n_slots`` slots with one memory per slot."""

    def __init__(self, loaded: LoadedSeparator, n_slots: int) -> None:
        if isinstance(n_slots, bool) or not isinstance(n_slots, int) or n_slots < 1:
            raise ConfigError(f"n_slots={n_slots!r} must be a positive int")
        self.loaded, self.n_slots = loaded, n_slots
        # BatchNorm folded, oneDNN weights prepacked: the trained model's numbers (to float tolerance),
        # several times faster per step (docs/separator.md, Inference speed)
        self.separator = fuse_for_inference(loaded.separator)
        self.device = next(self.separator.parameters()).device
        self.memory: torch.Tensor | None = None

    def class_indices(self, target_classes) -> np.ndarray:
        """Target category names (B,) -> the checkpoint's class indices."""
        return np.array([self.loaded.class_index(str(name)) for name in target_classes], np.int64)

    def step(self, audio: np.ndarray, class_index: np.ndarray, reset: np.ndarray, *,
             rows: np.ndarray | None = None) -> SeparationStep:
        """``audio`` (R, 2, N) float32 mixture of slots ``rows`` (default: all B), ``class_index`` (R,),
        ``reset`` (R,) bool: slots whose episode starts at this step (their memory is dropped)."""
        rows = np.arange(self.n_slots) if rows is None else np.asarray(rows, np.int64)
        audio = np.asarray(audio, np.float32)
        config = self.loaded.stft
        if audio.shape != (len(rows), N_EARS, config.clip_samples):
            raise AudioError(f"separator input must be ({len(rows)}, {N_EARS}, {config.clip_samples}) "
                             f"samples, got {audio.shape}")
        if not np.all(np.isfinite(audio)):
            raise AudioError("separator input holds NaN or infinite samples")
        reset = np.asarray(reset, bool)
        if reset.shape != (len(rows),):
            raise ConfigError(f"reset must be ({len(rows)},) bools, got shape {reset.shape}")
        if self.memory is None and not reset.all():
            raise ConfigError("the first step of every slot must reset its memory")
        sliced = network_input(stft(audio, config=config), n_slices=config.n_freq_slices)
        classes = torch.as_tensor(np.asarray(class_index, np.int64), device=self.device)
        index = torch.as_tensor(rows, device=self.device)
        with torch.inference_mode():
            memory = None if self.memory is None or reset.all() else self.memory[index]
            out = self.separator(sliced.to(self.device), classes, memory,
                                 None if memory is None else torch.as_tensor(reset, device=self.device))
            if self.memory is None:
                self.memory = torch.zeros((self.n_slots, *out.refined.shape[1:]), device=self.device)
            self.memory[index] = out.refined
        s = config.n_freq_slices
        return SeparationStep(binaural=from_slices(out.binaural.cpu().numpy(), n_slices=s),
                              monaural=from_slices(out.monaural.cpu().numpy(), n_slices=s)[:, 0],
                              refined=from_slices(out.refined.cpu().numpy(), n_slices=s)[:, 0])
