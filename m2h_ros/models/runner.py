"""The passive separator run step by step over episode slots: what the separator node (one slot) and
in-process evaluation (many) both call, so a ROS run and an in-process run compute the same numbers.

Each slot keeps its f^R memory; ``step(..., reset=...)`` starts a slot afresh (a new episode).
Outputs are numpy arrays in the (F, T) layout, linear magnitudes, made on first use from the networks'
sliced tensors (``SeparationStep.sliced``, which the PPO trainer feeds to the policy as they are).

With ``pose_cache`` > 0 and ``keys`` given, a slot keeps f^B's and f^M's outputs per key (a pose)
until its next reset: an agent that turns back to a heading it has heard hears the same clip again
(``BatchEnv`` without microphone noise), so f^B and f^M need not run again; f^R always runs, since its
memory has moved on. (An untrained policy revisits ~45% of its poses, a rotating one most of them.)
The cached rows then run f^B and f^M on one torch thread, whose results do not depend on which
other rows share the batch (with two threads oneDNN's last bits do), so a cached output is what a
recomputation gives bit for bit, and a run that restarts with an empty cache continues exactly.
"""

from __future__ import annotations

from collections import OrderedDict
from collections.abc import Hashable, Sequence
from concurrent.futures import ThreadPoolExecutor
from typing import NamedTuple

import numpy as np
import torch

from m2h_ros.core.audio.stft import AUDIO_OUTPUTS, from_slices, masked_mixture, rebuild_mixture_phase, stft
from m2h_ros.errors import AudioError, ConfigError
from m2h_ros.models.checkpoint import LoadedSeparator
from m2h_ros.models.inference import fuse_for_inference
from m2h_ros.models.listener import LoadedListener, listen
from m2h_ros.models.separator import N_EARS, network_input
from m2h_ros.models.threads import available_cpus, torch_threads

class SlicedSeparation(NamedTuple):
    """A step's separator outputs as the networks give them: sliced (B, C, H, W) tensors, channels_last."""

    binaural: torch.Tensor  # (B, 2S, H, W) f^B
    monaural: torch.Tensor  # (B, S, H, W) f^M
    refined: torch.Tensor  # (B, S, H, W) f^R


class SeparationStep:
    """One step's separator outputs for B slots (float32), numpy arrays in the (F, T) layout:
    ``binaural`` (B, 2, F, T) f^B (the target as heard, linear magnitude), ``monaural`` (B, F, T) f^M and
    ``refined`` (B, F, T) f^R (the memory carried to the next step).

    Built from the arrays, or (``SeparatorRunner.step``) from the networks' ``sliced`` tensors, each array
    then made on first use: the trainer feeds the tensors to the policy and reads only ``refined``."""

    def __init__(self, binaural: np.ndarray | None = None, monaural: np.ndarray | None = None,
                 refined: np.ndarray | None = None, *, sliced: SlicedSeparation | None = None,
                 mixture: tuple[np.ndarray, np.ndarray] | None = None) -> None:
        self._arrays = {"binaural": binaural, "monaural": monaural, "refined": refined}
        if (sliced is None) == any(array is None for array in self._arrays.values()):
            raise ConfigError("a SeparationStep takes its three arrays or its sliced tensors")
        self.sliced = sliced
        self.mixture = mixture  # the step's (B, 2, N) audio and its STFT, where the runner made it

    @property
    def binaural(self) -> np.ndarray:
        return self._array("binaural")

    @property
    def monaural(self) -> np.ndarray:
        return self._array("monaural")

    @property
    def refined(self) -> np.ndarray:
        return self._array("refined")

    def _array(self, name: str) -> np.ndarray:
        array = self._arrays[name]
        if array is None:
            tensor = getattr(self.sliced, name)
            array = from_slices(tensor.cpu().numpy(), n_slices=self.sliced.monaural.shape[1])
            self._arrays[name] = array = array if name == "binaural" else array[:, 0]
        return array

    def waveform(self, mixture: np.ndarray, *, config, output: str = "refined", binaural: bool = False) -> np.ndarray:
        """(B, N) audio for a listener, or with ``binaural`` (B, 2, N) where the output has two ears:
        ``masked_mixture``, f^B's mask on each ear of the mixture (the target as heard; ear mean unless
        binaural), or ``refined``, the refined estimate of the dry target rebuilt with the ear-mean
        mixture's phase (monaural: (B, N) always). The ``listener`` output is
        ``SeparatorRunner.listen``'s, not a step's."""
        if output == "masked_mixture":
            known = self.mixture is not None and np.array_equal(mixture, self.mixture[0])
            return masked_mixture(self.binaural, mixture, config=config, spec=self.mixture[1] if known else None,
                                  binaural=binaural)
        if output == "refined":
            return rebuild_mixture_phase(self.refined, mixture, config=config)
        if output == "listener":
            raise ConfigError("the listener output comes from SeparatorRunner.listen (a runner given a listener)")
        raise ConfigError(f"audio output {output!r}: one of {', '.join(AUDIO_OUTPUTS)}")


class SeparatorRunner:
    """f^B -> f^M -> f^R over ``n_slots`` slots with one memory per slot."""

    def __init__(self, loaded: LoadedSeparator, n_slots: int, *, pose_cache: int = 0,
                 listener: LoadedListener | None = None) -> None:
        if isinstance(n_slots, bool) or not isinstance(n_slots, int) or n_slots < 1:
            raise ConfigError(f"n_slots={n_slots!r} must be a positive int")
        if isinstance(pose_cache, bool) or not isinstance(pose_cache, int) or pose_cache < 0:
            raise ConfigError(f"pose_cache={pose_cache!r} must be an int >= 0 (keys kept per slot)")
        self.loaded, self.n_slots, self.pose_cache = loaded, n_slots, pose_cache
        # Per slot, key -> (binaural, monaural) sliced tensors of f^B and f^M, least recently used first.
        self._cache: list[OrderedDict[Hashable, tuple[torch.Tensor, torch.Tensor]]] = [
            OrderedDict() for _ in range(n_slots)]
        self.cache_hits = self.cache_misses = 0
        # BatchNorm folded, oneDNN weights prepacked: the trained model's numbers (to float tolerance),
        # several times faster per step (docs/design/separator.md, Inference speed)
        self.separator = fuse_for_inference(loaded.separator)
        self.device = next(self.separator.parameters()).device
        self.memory: torch.Tensor | None = None
        if listener is not None and listener.classes != loaded.classes:
            raise ConfigError(f"the listener {listener.path} knows classes {list(listener.classes)}, the separator "
                              f"{loaded.path} {list(loaded.classes)}: train the listener from this separator")
        self.listener = None if listener is None else fuse_for_inference(listener.listener)
        # A second thread for the single-threaded f^B / f^M of cache misses (where there is a second CPU).
        self._helper = ThreadPoolExecutor(max_workers=1, thread_name_prefix="separator") \
            if self.device.type == "cpu" and available_cpus() > 1 else None

    def class_indices(self, target_classes) -> np.ndarray:
        """Target category names (B,) -> the checkpoint's class indices."""
        return np.array([self.loaded.class_index(str(name)) for name in target_classes], np.int64)

    def step(self, audio: np.ndarray, class_index: np.ndarray, reset: np.ndarray, *,
             rows: np.ndarray | None = None, keys: Sequence[Hashable] | None = None) -> SeparationStep:
        """``audio`` (R, 2, N) float32 mixture of slots ``rows`` (default: all B), ``class_index`` (R,),
        ``reset`` (R,) bool: slots whose episode starts at this step (their memory is dropped);
        ``keys`` (R,) hashables (with ``pose_cache``): equal keys of a slot within an episode promise
        equal audio and class, so f^B and f^M's outputs are reused (see the module docstring)."""
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
        if keys is not None and len(keys) != len(rows):
            raise ConfigError(f"keys must be {len(rows)} hashables, got {len(keys)}")
        if self.memory is None and not reset.all():
            raise ConfigError("the first step of every slot must reset its memory")
        classes = torch.as_tensor(np.asarray(class_index, np.int64), device=self.device)
        index = torch.as_tensor(rows, device=self.device)
        with torch.inference_mode():
            spec = None
            if self.pose_cache and keys is not None:
                binaural, monaural = self._cached_front(audio, classes, reset, rows, keys)
            else:
                spec = stft(audio, config=config)
                binaural, monaural = self._front(audio, classes, spec)
            memory = None if self.memory is None or reset.all() else self.memory[index]
            refined = self.separator.refine(monaural, memory,
                                            None if memory is None else torch.as_tensor(reset, device=self.device))
            if self.memory is None:
                # channels_last, as f^R's outputs: rows move in and out without a transpose (~50x faster)
                self.memory = torch.zeros((self.n_slots, *refined.shape[1:]), device=self.device).contiguous(
                    memory_format=torch.channels_last)
            self.memory[index] = refined
        return SeparationStep(sliced=SlicedSeparation(binaural, monaural, refined),
                              mixture=None if spec is None else (audio, spec))

    def listen(self, audio: np.ndarray, class_index: np.ndarray, *, binaural: bool = True) -> np.ndarray:
        """The listener output for (B, 2, N) mixtures: (B, 2, N), or the ear mean (B, N) unless ``binaural``.
        Independent of the slots' memory: call it beside ``step`` with the same audio."""
        if self.listener is None:
            raise ConfigError("this runner has no listener: pass listener=load_listener(...)")
        ears = listen(self.listener, audio, class_index, config=self.loaded.stft)
        return ears if binaural else ears.mean(axis=1)

    def _front(self, audio: np.ndarray, classes: torch.Tensor,
               spec: np.ndarray | None = None) -> tuple[torch.Tensor, torch.Tensor]:
        """f^B and f^M: (separated binaural, monaural estimate), sliced (R, C, H, W); ``spec``: the STFT of
        ``audio``, where the caller has it."""
        spec = stft(audio, config=self.loaded.stft) if spec is None else spec
        sliced = network_input(spec, n_slices=self.loaded.stft.n_freq_slices)
        _, binaural = self.separator.separate_binaural(sliced.to(self.device), classes)
        return binaural, self.separator.predict_monaural(binaural, classes)

    def _single_thread_front(self, audio: np.ndarray, classes: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """``_front`` on one torch thread (batch-invariant results, module docstring): so the rows' two
        halves can run at once, one here and one on the helper thread (torch releases the GIL)."""
        with torch_threads(1):
            if self._helper is None or len(audio) < 2:
                return self._front(audio, classes)
            half = len(audio) // 2
            second = self._helper.submit(self._helper_front, audio[half:], classes[half:])
            first = self._front(audio[:half], classes[:half])
            second = second.result()
        return torch.cat((first[0], second[0])), torch.cat((first[1], second[1]))

    def _helper_front(self, audio: np.ndarray, classes: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        with torch.inference_mode():  # thread-local, as the thread count
            if torch.get_num_threads() != 1:
                torch.set_num_threads(1)
            return self._front(audio, classes)

    def _cached_front(self, audio: np.ndarray, classes: torch.Tensor, reset: np.ndarray, rows: np.ndarray,
                      keys: Sequence[Hashable]) -> tuple[torch.Tensor, torch.Tensor]:
        caches = [self._cache[slot] for slot in rows.tolist()]
        for cache, fresh in zip(caches, reset.tolist(), strict=True):
            if fresh:
                cache.clear()
        missed = [i for i, (cache, key) in enumerate(zip(caches, keys, strict=True)) if key not in cache]
        self.cache_hits += len(rows) - len(missed)
        self.cache_misses += len(missed)
        if missed:
            binaural, monaural = self._single_thread_front(audio[missed], classes[missed])
            for j, i in enumerate(missed):
                # Copies: a row view would keep its whole batch alive.
                caches[i][keys[i]] = binaural[j].clone(), monaural[j].clone()
                if len(caches[i]) > self.pose_cache:
                    caches[i].popitem(last=False)
            if len(missed) == len(rows):
                return binaural, monaural
        for cache, key in zip(caches, keys, strict=True):
            cache.move_to_end(key)
        entries = [cache[key] for cache, key in zip(caches, keys, strict=True)]
        return _stack_channels_last([e[0] for e in entries]), _stack_channels_last([e[1] for e in entries])


def _stack_channels_last(rows: list[torch.Tensor]) -> torch.Tensor:
    """(C, H, W) rows (channels_last slices) -> (R, C, H, W) channels_last: f^R runs ~30% faster on it than
    on torch.stack's NCHW, with the same numbers (its fused convolutions compute in channels_last)."""
    return torch.stack([row.permute(1, 2, 0) for row in rows]).permute(0, 3, 1, 2)
