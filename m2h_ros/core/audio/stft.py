"""Spectrogram front end of the separators (numpy/scipy; no torch).

The paper's STFT: Hann window of 1023 samples (63.9 ms at 16 kHz), hop 512 samples (32 ms), FFT size
1023, centred frames with reflect padding -> 512 frequency bins x 32 frames for a 1 s clip. This
module reproduces ``torch.stft(x, n_fft=1023, hop_length=512, win_length=1023,
window=torch.hann_window(1023), center=True, pad_mode='reflect', return_complex=True)`` and its
``torch.istft`` inverse (the original code's ``librosa.istft`` omitted ``n_fft`` and rebuilt
waveforms at only 1.5-10 dB SNR; we invert exactly, so compare reconstructions with the paper with
that in mind).

Layouts (all functions are batched over leading dimensions):
  waveform        (..., N)
  spectrogram     (..., F, T) complex, F = n_fft // 2 + 1 = 512, T = 1 + N // hop = 32
  sliced          (..., C * S, F // S, T) with S = 16 slices: channel ``c * S + s`` holds input
                  channel c, frequency bins [s * F // S, (s + 1) * F // S) (channel-major, as in the
                  original code). The target-class constant channel goes after all sliced channels.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass
from functools import lru_cache
from typing import Any, TypeVar

import numpy as np
import scipy.fft

from m2h_ros.config import reject_unknown_fields
from m2h_ros.core.audio.metrics import all_finite
from m2h_ros.errors import AudioError, ConfigError

Reshapeable = TypeVar("Reshapeable")  # numpy array or torch tensor: slicing only uses .shape and .reshape

_PAD_MODES = ("reflect", "constant")


@dataclass(frozen=True)
class StftConfig:
    """STFT settings; the defaults are the paper's and give 512 x 32 per channel for a 1 s clip."""

    sample_rate: int = 16000
    clip_samples: int = 16000
    n_fft: int = 1023
    hop_length: int = 512
    win_length: int = 1023
    center: bool = True
    pad_mode: str = "reflect"
    n_freq_slices: int = 16

    def __post_init__(self) -> None:
        for name in ("sample_rate", "clip_samples", "n_fft", "hop_length", "win_length", "n_freq_slices"):
            value = getattr(self, name)
            if not isinstance(value, int) or isinstance(value, bool) or value <= 0:
                raise ConfigError(f"StftConfig.{name} must be a positive int, got {value!r}")
        if self.win_length > self.n_fft:
            raise ConfigError(f"StftConfig.win_length must be <= n_fft ({self.n_fft}), got {self.win_length}")
        if self.hop_length > self.win_length:
            raise ConfigError(f"StftConfig.hop_length must be <= win_length ({self.win_length}), got {self.hop_length}")
        if self.pad_mode not in _PAD_MODES:
            raise ConfigError(f"StftConfig.pad_mode must be one of {_PAD_MODES}, got {self.pad_mode!r}")
        if self.n_freq % self.n_freq_slices:
            raise ConfigError(
                f"StftConfig.n_freq_slices must divide the {self.n_freq} frequency bins, got {self.n_freq_slices}"
            )

    @property
    def n_freq(self) -> int:
        """Frequency bins of the one-sided spectrum (512 for n_fft 1023)."""
        return self.n_fft // 2 + 1

    @property
    def n_frames(self) -> int:
        """Frames for one clip of ``clip_samples`` samples (32 for 16000 samples)."""
        return self.frames_for(self.clip_samples)

    @property
    def window_ms(self) -> float:
        return 1000.0 * self.win_length / self.sample_rate

    @property
    def hop_ms(self) -> float:
        return 1000.0 * self.hop_length / self.sample_rate

    @property
    def slice_shape(self) -> tuple[int, int]:
        """(height, width) of one sliced channel: (32, 32) for the paper's settings."""
        return self.n_freq // self.n_freq_slices, self.n_frames

    def frames_for(self, n_samples: int) -> int:
        if self.center:
            return 1 + n_samples // self.hop_length
        return 1 + (n_samples - self.n_fft) // self.hop_length

    def window(self) -> np.ndarray:
        """Periodic Hann window (= torch.hann_window(win_length)), zero-padded to n_fft, float64: as
        scipy.signal.get_window("hann", win_length) computes it, bit for bit (tested), without the
        half second that importing scipy.signal adds to every process's start."""
        window = (0.5 + 0.5 * np.cos(np.linspace(-np.pi, np.pi, self.win_length + 1)))[:-1] \
            if self.win_length > 1 else np.ones(self.win_length)
        left = (self.n_fft - self.win_length) // 2
        return np.pad(window, (left, self.n_fft - self.win_length - left))

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)

    @classmethod
    def from_dict(cls, values: dict[str, Any]) -> StftConfig:
        reject_unknown_fields(cls, values)
        return cls(**values)


DEFAULT_STFT = StftConfig()


@lru_cache(maxsize=16)
def _cached_window(config: StftConfig, dtype: np.dtype) -> np.ndarray:
    """Read-only ``config.window()`` in ``dtype``: building it costs more than a 1 s clip's FFTs."""
    window = config.window().astype(dtype)
    window.flags.writeable = False
    return window


@lru_cache(maxsize=16)
def _ola_envelope(config: StftConfig, n_frames: int, dtype: np.dtype) -> np.ndarray:
    """Read-only overlap-added square of the ``dtype`` window, in float64, ``n_frames`` frames, untrimmed."""
    window_sq = _cached_window(config, dtype).astype(np.float64) ** 2
    hop, n_fft = config.hop_length, config.n_fft
    envelope = np.zeros(n_fft + hop * (n_frames - 1))
    for t in range(n_frames):
        envelope[t * hop : t * hop + n_fft] += window_sq
    envelope.flags.writeable = False
    return envelope


def _check_finite(x: np.ndarray, what: str) -> None:
    if not all_finite(x):
        raise AudioError(f"{what} holds NaN or infinite values")


def stft(waveform: np.ndarray, *, config: StftConfig = DEFAULT_STFT) -> np.ndarray:
    """Complex spectrogram (..., F, T) of a real waveform (..., N); complex64 for float32 input."""
    x = np.asarray(waveform)
    if x.ndim < 1 or not np.issubdtype(x.dtype, np.floating):
        raise AudioError(f"stft expects a real float waveform (..., N), got dtype {x.dtype} shape {x.shape}")
    _check_finite(x, "stft input")
    pad = config.n_fft // 2
    if config.center:
        if config.pad_mode == "reflect" and x.shape[-1] <= pad:
            raise AudioError(f"stft with reflect padding needs more than {pad} samples, got {x.shape[-1]}")
        if config.pad_mode == "reflect":  # = np.pad(mode="reflect"), without its per-call overhead
            x = np.concatenate([x[..., pad:0:-1], x, x[..., -2 : -pad - 2 : -1]], axis=-1)
        else:
            x = np.pad(x, [(0, 0)] * (x.ndim - 1) + [(pad, pad)], mode=config.pad_mode)
    if x.shape[-1] < config.n_fft:
        raise AudioError(f"stft needs at least n_fft={config.n_fft} samples after padding, got {x.shape[-1]}")
    x = np.ascontiguousarray(x)
    n_frames = 1 + (x.shape[-1] - config.n_fft) // config.hop_length
    step = x.strides[-1]
    frames = np.lib.stride_tricks.as_strided(x, (*x.shape[:-1], n_frames, config.n_fft),
                                             (*x.strides[:-1], config.hop_length * step, step), writeable=False)
    # Transformed along the frame axis of the transposed frames, so that the result comes out
    # C-contiguous in the (..., F, T) layout (same numbers): a swapped view would make every later
    # elementwise pass into (..., F, T) arrays (|X|, log) strided, ~5x slower.
    return scipy.fft.rfft(np.swapaxes(frames * _cached_window(config, x.dtype), -1, -2), axis=-2)


def istft(spec: np.ndarray, *, config: StftConfig = DEFAULT_STFT, length: int | None = None) -> np.ndarray:
    """Inverse of :func:`stft` by windowed overlap-add (= torch.istft with the same settings).

    ``length`` trims (or zero-pads) the output; ``None`` gives torch's default for centred frames,
    hop * (T - 1) + n_fft - 2 * (n_fft // 2) samples (15873 for 32 frames), so pass
    ``length=config.clip_samples`` to get a 1 s clip back.
    """
    spec = np.asarray(spec)
    if spec.ndim < 2 or spec.shape[-2] != config.n_freq:
        raise AudioError(f"istft expects (..., {config.n_freq}, T) spectrograms, got shape {spec.shape}")
    _check_finite(spec, "istft input")
    real_dtype = np.float32 if spec.dtype == np.complex64 else np.float64
    window = _cached_window(config, np.dtype(real_dtype))
    n_frames, hop, n_fft = spec.shape[-1], config.hop_length, config.n_fft
    frames = scipy.fft.irfft(np.swapaxes(spec, -1, -2), n=n_fft, axis=-1)  # (..., T, n_fft)
    frames *= window
    # Overlap-add chunk by chunk: each frame is cut into ceil(n_fft / hop) hop-long pieces (the last
    # one shorter), and piece j of frame t lands at (t + j) * hop, so one vectorised add per piece
    # index does the whole job.
    n_chunks = -(-n_fft // hop)
    out = np.zeros((*frames.shape[:-2], n_frames + n_chunks - 1, hop), dtype=real_dtype)
    for j in range(n_chunks):
        width = min(hop, n_fft - j * hop)
        out[..., j : j + n_frames, :width] += frames[..., j * hop : j * hop + width]
    out = out.reshape(*out.shape[:-2], -1)[..., : n_fft + hop * (n_frames - 1)]
    start = n_fft // 2 if config.center else 0
    stop = out.shape[-1] - (n_fft // 2 if config.center else 0)
    if length is not None:
        stop = start + length
    out, envelope = out[..., start:stop], _ola_envelope(config, n_frames, np.dtype(real_dtype))[start:stop]
    if np.any(envelope < 1e-11):
        raise AudioError("istft window overlap-add envelope has zeros (settings break NOLA)")
    # Divided in float64 (the envelope's type) and rounded into real_dtype on the way out, without a
    # float64 copy of the whole batch.
    result = np.empty(out.shape, real_dtype)
    np.divide(out, envelope, out=result, casting="same_kind")
    if length is not None and result.shape[-1] < length:
        result = np.pad(result, [(0, 0)] * (result.ndim - 1) + [(0, length - result.shape[-1])])
    return result


def log_magnitude(spec: np.ndarray) -> np.ndarray:
    """Network input feature log(1 + |X|)."""
    return np.log1p(np.abs(spec))


def to_slices(x: Reshapeable, *, n_slices: int = DEFAULT_STFT.n_freq_slices) -> Reshapeable:
    """(..., C, F, T) -> (..., C * n_slices, F // n_slices, T); channel c * n_slices + s = band s of c.

    Uses only ``.shape`` and ``.reshape``, so it works on numpy arrays and torch tensors alike.
    """
    *lead, channels, n_freq, n_frames = x.shape
    if n_freq % n_slices:
        raise AudioError(f"to_slices: {n_freq} frequency bins do not split into {n_slices} slices")
    return x.reshape(*lead, channels * n_slices, n_freq // n_slices, n_frames)


def from_slices(x: Reshapeable, *, n_slices: int = DEFAULT_STFT.n_freq_slices) -> Reshapeable:
    """Inverse of :func:`to_slices`: (..., C * n_slices, F // n_slices, T) -> (..., C, F, T)."""
    *lead, sliced_channels, height, n_frames = x.shape
    if sliced_channels % n_slices:
        raise AudioError(f"from_slices: {sliced_channels} channels are not a multiple of {n_slices} slices")
    return x.reshape(*lead, sliced_channels // n_slices, n_slices * height, n_frames)


def class_channel_value(class_index: int | np.ndarray) -> np.ndarray:
    """Constant value of the target-class channel: index + 1, so class 0 is not an all-zero plane."""
    return np.asarray(class_index, dtype=np.float32) + 1.0


def append_class_channel(sliced: np.ndarray, class_index: int | np.ndarray) -> np.ndarray:
    """(..., K, H, W) + class index (scalar or shape (...)) -> (..., K + 1, H, W), class plane last."""
    value = class_channel_value(class_index)
    plane = np.broadcast_to(value[..., None, None, None], (*sliced.shape[:-3], 1, *sliced.shape[-2:]))
    return np.concatenate([sliced, plane.astype(sliced.dtype)], axis=-3)


# --- rebuilding waveforms from a predicted magnitude -------------------------------------------------


def rebuild_with_phase(magnitude: np.ndarray, phase_spec: np.ndarray, *, config: StftConfig = DEFAULT_STFT,
                       length: int | None = None) -> np.ndarray:
    """Waveform from a magnitude (..., F, T) and the phase of the complex spectrogram ``phase_spec``."""
    magnitude = np.asarray(magnitude)
    if magnitude.shape != np.shape(phase_spec):
        raise AudioError(f"magnitude shape {magnitude.shape} differs from phase shape {np.shape(phase_spec)}")
    phase_spec = np.asarray(phase_spec)
    # magnitude * exp(1j * angle(X)) = X * (magnitude / |X|): no trigonometry and a real division
    # instead of a complex one (several times faster); angle(0) = 0, so a silent bin gets phase 1.
    size = np.abs(phase_spec)
    silent = size == 0
    spec = phase_spec * (magnitude / np.where(silent, 1, size))
    np.copyto(spec, magnitude, where=silent)
    return istft(spec.astype(np.complex64 if magnitude.dtype == np.float32 else np.complex128, copy=False),
                 config=config, length=length)


def rebuild_ground_truth_phase(magnitude: np.ndarray, target_monaural: np.ndarray, *,
                               config: StftConfig = DEFAULT_STFT) -> np.ndarray:
    """Paper's reported variant: predicted magnitude + phase of the ground-truth monaural target.

    Needs the clean target (an oracle): use it for comparability with the paper's numbers only.
    """
    target = np.asarray(target_monaural)
    return rebuild_with_phase(magnitude, stft(target, config=config), config=config, length=target.shape[-1])


def rebuild_mixture_phase(magnitude: np.ndarray, binaural_mixture: np.ndarray, *,
                          config: StftConfig = DEFAULT_STFT) -> np.ndarray:
    """Deployable variant: predicted magnitude + phase of the mean of the two mixture channels."""
    mixture = np.asarray(binaural_mixture)
    if mixture.ndim < 2 or mixture.shape[-2] != 2:
        raise AudioError(f"binaural mixture must have shape (..., 2, N), got {mixture.shape}")
    mono = mixture.mean(axis=-2)
    return rebuild_with_phase(magnitude, stft(mono, config=config), config=config, length=mono.shape[-1])


# What a listener is given (separator_node's audio_output); the first is the default.
AUDIO_OUTPUTS = ("listener", "masked_mixture", "refined")
AUDIO_CHANNELS = ("binaural", "mono")


def masked_mixture(binaural_magnitude: np.ndarray, binaural_mixture: np.ndarray, *,
                   config: StftConfig = DEFAULT_STFT, spec: np.ndarray | None = None,
                   binaural: bool = False) -> np.ndarray:
    """A separated binaural magnitude (..., 2, F, T) with each ear's own mixture phase: ear mean (..., N),
    or with ``binaural`` both ears (..., 2, N); ``spec``: the mixture's STFT, where the caller has it (the
    separator computed it for its input).

    f^B predicts a ratio mask on each ear's mixture; applied there, each ear keeps its own timing and
    room, which the mean then adds coherently: the target as the microphones heard it, less the
    distractor (docs/design/separator.md, "What a listener gets")."""
    mixture = np.asarray(binaural_mixture)
    if mixture.ndim < 2 or mixture.shape[-2] != 2:
        raise AudioError(f"binaural mixture must have shape (..., 2, N), got {mixture.shape}")
    ears = rebuild_with_phase(binaural_magnitude, stft(mixture, config=config) if spec is None else spec,
                              config=config, length=mixture.shape[-1])
    return ears if binaural else ears.mean(axis=-2)
