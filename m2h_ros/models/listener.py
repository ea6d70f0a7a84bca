"""The listener output: what ``separator/audio`` plays to a person or hands to a speech recogniser,
trained for that (docs/design/separator.md, "What a listener gets"), beside the paper's f^B / f^M / f^R,
which it leaves untouched.

A U-Net of f^B's shape, started from f^B's weights, reads the mixture's log magnitudes (2S sliced
channels, as f^B), the class plane, and the interaural phase difference of every bin (its cosine and
sine, 2S more channels, whose first-layer weights start at zero). It returns, for each ear e, the
complex spectrum

    Y_e(t) = sigmoid(m_e(t)) * X_e(t) + sum_j sum_k c_ejk(t) * X_j(t - k)   (j over both ears, k < taps)

a ratio mask on the ear's own mixture (f^B's head, so the untrained model *is* f^B's masked mixture)
plus a per-bin two-ear complex filter over the current and ``filter_taps - 1`` earlier frames (a
zero-initialised 1x1 head): a learned beamformer per bin that can use the phase, which f^B's magnitude
mask cannot, to take out the distractor, and with earlier frames the late reverberation (which the
past of the same bin predicts). Trained on the waveform (SI-SDR against the target's early image at each ear and at
the ear mean; ``training/listener_train.py``), so it keeps both ears (binaural output, ear mean for a
monaural listener).
"""

from __future__ import annotations

import os
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import torch
from torch import nn

from m2h_ros.config import reject_unknown_fields
from m2h_ros.core.audio.stft import DEFAULT_STFT, StftConfig, from_slices, istft, stft, to_slices
from m2h_ros.errors import AudioError, CheckpointError, ConfigError
from m2h_ros.models.checkpoint import (class_index_in, load_state_checked, model_settings, read_checkpoint,
                                      write_checkpoint)
from m2h_ros.models.separator import N_EARS, Separator
from m2h_ros.models.unet import UNet
from m2h_ros.paths import PACKAGE_DIR

LISTENER_KIND = "m2h_listener"
LISTENER_VERSION = 1
DEFAULT_LISTENER_CHECKPOINT = PACKAGE_DIR / "models" / "default" / "listener.pt"
_PHASE_FLOOR = 1e-8  # |X_L X_R*| below this: the bin's phase difference reads as 0 (cos 1, sin 0)
# Per output ear, per input ear, real and imaginary part of a complex filter coefficient.
_FILTER_TERMS = N_EARS * N_EARS * 2


@dataclass(frozen=True)
class ListenerConfig:
    """Model arguments of :class:`Listener` (stored in its checkpoint)."""

    unet_channels: tuple[int, ...] = (16, 32, 64, 64, 64)
    n_freq_slices: int = 16
    filter_taps: int = 1  # frames the two-ear filter reads per bin: the current one and taps - 1 before it

    def __post_init__(self) -> None:
        channels = tuple(self.unet_channels) if isinstance(self.unet_channels, (list, tuple)) else ()
        if len(channels) != 5 or any(not isinstance(c, int) or isinstance(c, bool) or c <= 0 for c in channels):
            raise ConfigError(f"ListenerConfig.unet_channels must be 5 positive ints, got {self.unet_channels!r}")
        object.__setattr__(self, "unet_channels", channels)
        for name in ("n_freq_slices", "filter_taps"):
            value = getattr(self, name)
            if not isinstance(value, int) or isinstance(value, bool) or value <= 0:
                raise ConfigError(f"ListenerConfig.{name} must be a positive int, got {value!r}")

    @property
    def ear_channels(self) -> int:
        """Sliced channels of one binaural plane (2S)."""
        return N_EARS * self.n_freq_slices

    def check_stft(self, stft_config: StftConfig) -> None:
        if stft_config.n_freq_slices != self.n_freq_slices:
            raise ConfigError(f"StftConfig.n_freq_slices={stft_config.n_freq_slices} but the listener expects "
                              f"{self.n_freq_slices}")
        height, width = stft_config.slice_shape
        if height % 32 or width % 32:
            raise ConfigError(f"sliced planes {height}x{width} must be multiples of 32 for the listener's U-Net")

    def to_dict(self) -> dict[str, Any]:
        return {**asdict(self), "unet_channels": list(self.unet_channels)}

    @classmethod
    def from_dict(cls, values: dict[str, Any]) -> ListenerConfig:
        reject_unknown_fields(cls, values)
        return cls(**{**values, "unet_channels": tuple(values.get("unet_channels", cls.unet_channels))})


class Listener(nn.Module):
    """Mixture spectrum (B, 2, F, T) complex + class index (B,) -> target's binaural spectrum (B, 2, F, T)."""

    def __init__(self, config: ListenerConfig | None = None) -> None:
        super().__init__()
        self.config = config = config or ListenerConfig()
        ears = config.ear_channels
        # Input: [log(1 + |X|) (2S), class plane, cos and sin of the interaural phase difference (2S)]
        self.unet = UNet(ears + 1 + ears, ears, config.unet_channels)
        self.filter_head = nn.Conv2d(ears, _FILTER_TERMS * config.filter_taps * config.n_freq_slices, kernel_size=1)
        nn.init.zeros_(self.filter_head.weight)
        nn.init.zeros_(self.filter_head.bias)

    @classmethod
    def from_separator(cls, separator: Separator, *, filter_taps: int = 1) -> Listener:
        """A listener whose output is, before training, f^B's mask on each ear's mixture: f^B's U-Net
        weights copied, the phase inputs' first-layer weights and the filter head at zero."""
        if separator.config.backbone != "unet":
            raise ConfigError(f"a listener starts from a U-Net f^B; this separator's is {separator.config.backbone!r}")
        listener = cls(ListenerConfig(unet_channels=separator.config.unet_channels,
                                      n_freq_slices=separator.config.n_freq_slices, filter_taps=filter_taps))
        source = separator.binaural_separator.state_dict()
        own = listener.unet.state_dict()
        for name, tensor in source.items():
            if own[name].shape == tensor.shape:
                own[name] = tensor.clone()
            else:  # the first convolution: f^B's inputs first, the phase channels after them at zero
                own[name] = torch.zeros_like(own[name])
                own[name][:, : tensor.shape[1]] = tensor
        listener.unet.load_state_dict(own)
        return listener

    def forward(self, spec: torch.Tensor, class_index: torch.Tensor) -> torch.Tensor:
        if spec.ndim != 4 or spec.shape[1] != N_EARS or not spec.is_complex():
            raise AudioError(f"listener input must be a complex (B, {N_EARS}, F, T) spectrum, got "
                             f"{spec.dtype} {tuple(spec.shape)}")
        slices = self.config.n_freq_slices
        batch, _, n_freq, n_frames = spec.shape
        cross = spec[:, 0] * spec[:, 1].conj()
        unit = cross / cross.abs().clamp_min(_PHASE_FLOOR)
        phase = torch.stack((unit.real, unit.imag), dim=1)
        plane = (class_index.to(torch.float32) + 1.0).reshape(-1, 1, 1, 1).expand(batch, 1, n_freq // slices, n_frames)
        features = torch.cat((to_slices(torch.log1p(spec.abs()), n_slices=slices), plane,
                              to_slices(phase, n_slices=slices)), dim=1)
        hidden = self.unet.features(features)
        mask = from_slices(torch.sigmoid(self.unet.head(hidden)), n_slices=slices)  # (B, 2, F, T)
        taps = self.config.filter_taps
        terms = from_slices(self.filter_head(hidden), n_slices=slices).reshape(
            batch, N_EARS, N_EARS * taps, 2, n_freq, n_frames)
        coefficients = torch.complex(terms[:, :, :, 0], terms[:, :, :, 1])  # (B, out ear, in ear x tap, F, T)
        # X_j(t - k) for every ear j and tap k, zero before the frame's start: (B, 2 * taps, F, T)
        past = torch.nn.functional.pad(spec, (taps - 1, 0)) if taps > 1 else spec
        delayed = torch.cat([past[..., taps - 1 - k: taps - 1 - k + n_frames] for k in range(taps)], dim=1)
        return mask * spec + (coefficients * delayed[:, None]).sum(dim=2)


def listen(listener: Listener, mixture: np.ndarray, class_index: np.ndarray, *,
           config: StftConfig = DEFAULT_STFT) -> np.ndarray:
    """(B, 2, N) binaural mixture -> (B, 2, N) the target's binaural early image as the listener
    estimates it. Runs under ``torch.inference_mode()``; call ``listener.eval()`` first (or pass
    ``models.inference.fuse_for_inference(listener)``)."""
    mixture = np.asarray(mixture, np.float32)
    if mixture.ndim != 3 or mixture.shape[1] != N_EARS:
        raise AudioError(f"binaural mixture must be (B, {N_EARS}, N), got {mixture.shape}")
    listener.config.check_stft(config)
    spec = stft(mixture, config=config)  # raises AudioError on NaN / infinite samples
    device = next(listener.parameters()).device
    classes = torch.as_tensor(np.broadcast_to(np.asarray(class_index, np.int64), (mixture.shape[0],)).copy(),
                              device=device)
    with torch.inference_mode():
        out = listener(torch.from_numpy(spec).to(device), classes).cpu().numpy()
    return istft(out, config=config, length=mixture.shape[-1])


@dataclass(frozen=True)
class LoadedListener:
    """A listener rebuilt from its checkpoint (eval mode), with its STFT settings and class names."""

    listener: Listener
    stft: StftConfig
    classes: tuple[str, ...]
    path: Path
    metadata: dict[str, Any] = field(default_factory=dict)

    def class_index(self, name: str) -> int:
        return class_index_in(self.classes, name, model="listener")


def save_listener(path: str | os.PathLike, listener: Listener, *, classes: tuple[str, ...] | list[str],
                  stft_config: StftConfig = DEFAULT_STFT, metadata: dict[str, Any] | None = None) -> Path:
    listener.config.check_stft(stft_config)
    return write_checkpoint(path, kind=LISTENER_KIND, model_args=listener.config.to_dict(),
                            state_dict=listener.state_dict(), metadata=metadata, stft=stft_config.to_dict(),
                            classes=list(classes), listener_version=LISTENER_VERSION)


def load_listener(path: str | os.PathLike, *, map_location: str | torch.device = "cpu") -> LoadedListener:
    path = Path(path)
    if not path.is_file() and path.resolve() == DEFAULT_LISTENER_CHECKPOINT.resolve():
        raise CheckpointError(f"shipped listener checkpoint {path} not found; build it with the command in "
                              "docs/results/listener/README.md (scripts/train_listener.py)")
    payload = read_checkpoint(path, kind=LISTENER_KIND, map_location=map_location)
    if payload.get("listener_version") != LISTENER_VERSION:
        raise CheckpointError(f"checkpoint {path} is listener version {payload.get('listener_version')!r}; "
                              f"this code reads version {LISTENER_VERSION}: train it again (scripts/train_listener.py)")
    config, stft_config = model_settings(payload, path, ListenerConfig)
    listener = Listener(config)
    load_state_checked(listener, payload["state_dict"], path=path)
    return LoadedListener(listener.to(map_location).eval(), stft_config, tuple(payload["classes"]), path,
                          dict(payload["metadata"]))
