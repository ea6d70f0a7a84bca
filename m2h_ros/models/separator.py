"""The passive separator of Move2Hear: f^B (binaural) -> f^M (monaural) -> f^R (acoustic memory).

All tensors are in the sliced layout of :mod:`m2h_ros.core.audio.stft` (channel ``c * S + s`` = band
s of input channel c, S = 16 slices of 32 bins, 32 frames): with the paper's STFT a binaural
magnitude is (B, 32, 32, 32) and a monaural one (B, 16, 32, 32).

f^B and f^M are U-Nets (``backbone="unet"``, the paper's) or MMDenseNet-style multi-band dense nets
(``backbone="mmdensenet"``, ``models.mmdensenet``: experiment 5); same inputs and outputs either way.

* f^B: U-Net on [log(1 + |mixture|) (2S channels), class plane] -> sigmoid ratio mask (2S channels),
  applied to the linear mixture magnitude -> separated binaural magnitude. (The original code uses
  the unbounded 1x1-conv output as the mask; a sigmoid keeps it in [0, 1], the ideal-ratio-mask range.)
* f^M: U-Net on [log(1 + separated binaural), class plane] -> non-negative gain (softplus / ln 2, so
  a zero score is gain 1) applied to the ear average of the separated binaural magnitude -> target
  monaural magnitude (S channels). (The original code feeds f^M no class plane and regresses the
  magnitude directly with an unbounded output; predicting absolute linear magnitudes from log input
  barely learned here, a gain on the ear average learns quickly.)
* f^R: 2-conv refiner on [current f^M estimate, previous refined estimate] -> correction added to the
  current estimate, clamped at 0 -> refined magnitude, which is also the memory for the next step.
  Its last conv starts at zero, so the untrained refiner is the identity. At an episode's first step
  the previous estimate is the current one (memory reset).

The class plane holds ``class_index + 1`` (as ``core.audio.stft.class_channel_value``).
"""

from __future__ import annotations

from dataclasses import asdict, dataclass
from typing import Any, NamedTuple

import numpy as np
import torch
import torch.nn.functional as F
from torch import nn

from m2h_ros.core.audio.stft import DEFAULT_STFT, StftConfig, from_slices, rebuild_with_phase, stft
from m2h_ros.config import reject_unknown_fields
from m2h_ros.errors import AudioError, ConfigError
from m2h_ros.models.mmdensenet import DOWNSAMPLING, MMDenseNet, band_slices
from m2h_ros.models.unet import MemoryRefiner, UNet

PRESET_NAMES = ("paper", "compact")
# f^B / f^M networks: the paper's U-Net, or the MMDenseNet-style multi-band dense net (experiment 5).
BACKBONES = ("unet", "mmdensenet")
N_EARS = 2  # binaural input
_INV_LN2 = 1.0 / float(np.log(2.0))  # softplus(0) * this = gain 1
# Version of the output parameterisation, stored in checkpoints: weights of another version have the
# same shapes but mean something else. 1: f^M absolute magnitude (softplus), f^R absolute (softplus);
# 2: f^M gain on the ear-averaged binaural estimate, f^R residual with a zero-initialised last conv.
SEPARATOR_VERSION = 2


@dataclass(frozen=True)
class SeparatorConfig:
    """Model arguments of :class:`Separator` (stored in checkpoints as a dict)."""

    unet_channels: tuple[int, ...] = (16, 32, 64, 64, 64)
    refiner_hidden: int = 32
    n_freq_slices: int = 16
    # Checkpoints written before this field existed hold U-Nets: the default keeps them loading.
    backbone: str = "unet"
    dense_growth: int = 8  # MMDenseNet only: the growth rate (width) of every dense block

    def __post_init__(self) -> None:
        channels = tuple(self.unet_channels) if isinstance(self.unet_channels, (list, tuple)) else ()
        if len(channels) != 5 or any(not isinstance(c, int) or isinstance(c, bool) or c <= 0 for c in channels):
            raise ConfigError(f"SeparatorConfig.unet_channels must be 5 positive ints, got {self.unet_channels!r}")
        object.__setattr__(self, "unet_channels", channels)
        for name in ("refiner_hidden", "n_freq_slices", "dense_growth"):
            value = getattr(self, name)
            if not isinstance(value, int) or isinstance(value, bool) or value <= 0:
                raise ConfigError(f"SeparatorConfig.{name} must be a positive int, got {value!r}")
        if self.backbone not in BACKBONES:
            raise ConfigError(f"SeparatorConfig.backbone must be one of {BACKBONES}, got {self.backbone!r}")
        if self.backbone == "mmdensenet":
            band_slices(self.n_freq_slices)  # every band needs a slice

    @classmethod
    def preset(cls, name: str) -> SeparatorConfig:
        """``paper``: widths 64..512 as published; ``compact``: 16, 32, 64, 64, 64 (the shipped default)."""
        if name == "paper":
            return cls(unet_channels=(64, 128, 256, 512, 512))
        if name == "compact":
            return cls()
        raise ConfigError(f"unknown separator preset {name!r}; choose one of {PRESET_NAMES}")

    @property
    def summary(self) -> str:
        """The backbone and its widths, for logs: ``unet 16-32-64-64-64`` or ``mmdensenet growth 8``."""
        if self.backbone == "unet":
            return "unet " + "-".join(str(c) for c in self.unet_channels)
        return f"{self.backbone} growth {self.dense_growth}"

    @property
    def binaural_channels(self) -> int:
        return N_EARS * self.n_freq_slices

    @property
    def monaural_channels(self) -> int:
        return self.n_freq_slices

    def check_stft(self, stft_config: StftConfig) -> None:
        """Raise ConfigError unless the STFT's sliced planes fit this model."""
        if stft_config.n_freq_slices != self.n_freq_slices:
            raise ConfigError(
                f"StftConfig.n_freq_slices={stft_config.n_freq_slices} but the separator expects {self.n_freq_slices}"
            )
        height, width = stft_config.slice_shape
        multiple = 32 if self.backbone == "unet" else DOWNSAMPLING
        if height % multiple or width % multiple:
            raise ConfigError(f"sliced planes {height}x{width} must be multiples of {multiple} for the {self.backbone}")

    def to_dict(self) -> dict[str, Any]:
        values = asdict(self)
        values["unet_channels"] = list(self.unet_channels)
        return values

    @classmethod
    def from_dict(cls, values: dict[str, Any]) -> SeparatorConfig:
        reject_unknown_fields(cls, values)
        return cls(**{**values, "unet_channels": tuple(values.get("unet_channels", cls.unet_channels))})


def backbone(config: SeparatorConfig, out_channels: int) -> nn.Module:
    """f^B's or f^M's network: [binaural planes (2S), class plane] -> ``out_channels`` raw scores."""
    if config.backbone == "mmdensenet":
        return MMDenseNet(out_channels, groups=N_EARS, n_slices=config.n_freq_slices, extra=1,
                          growth=config.dense_growth)
    return UNet(config.binaural_channels + 1, out_channels, config.unet_channels)


class SeparatorStep(NamedTuple):
    """One step's outputs, all in the sliced layout."""

    mask: torch.Tensor  # (B, 2S, H, W) ratio mask in [0, 1]
    binaural: torch.Tensor  # (B, 2S, H, W) separated binaural magnitude = mask * mixture
    monaural: torch.Tensor  # (B, S, H, W) f^M estimate of the target's monaural magnitude
    refined: torch.Tensor  # (B, S, H, W) f^R estimate; pass it back as the next step's memory


class Separator(nn.Module):
    """f^B -> f^M -> f^R for one step, with the memory passed in and out explicitly."""

    def __init__(self, config: SeparatorConfig | None = None) -> None:
        super().__init__()
        self.config = config = config or SeparatorConfig()
        bins, monos = config.binaural_channels, config.monaural_channels
        self.binaural_separator = backbone(config, bins)
        self.monaural_predictor = backbone(config, monos)
        self.refiner = MemoryRefiner(monos, config.refiner_hidden)

    @staticmethod
    def _with_class_plane(features: torch.Tensor, class_index: torch.Tensor) -> torch.Tensor:
        value = class_index.to(features.dtype).reshape(-1, 1, 1, 1) + 1.0
        # The plane takes the features' memory layout (e.g. channels_last), so cat keeps it and the
        # convolutions get the layout they run fastest in, without a conversion.
        plane = torch.empty_like(features[:, :1])
        plane.copy_(value.expand_as(plane))
        return torch.cat((features, plane), dim=1)

    def separate_binaural(self, mixture: torch.Tensor, class_index: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """f^B: mixture magnitude (B, 2S, H, W) -> (mask, separated binaural magnitude)."""
        if mixture.ndim != 4 or mixture.shape[1] != self.config.binaural_channels:
            raise AudioError(
                f"mixture magnitude must be (B, {self.config.binaural_channels}, H, W), got {tuple(mixture.shape)}"
            )
        mask = torch.sigmoid(self.binaural_separator(self._with_class_plane(torch.log1p(mixture), class_index)))
        return mask, mask * mixture

    def predict_monaural(self, binaural: torch.Tensor, class_index: torch.Tensor) -> torch.Tensor:
        """f^M: separated binaural magnitude (B, 2S, H, W) -> monaural magnitude (B, S, H, W), as a
        predicted gain times the ear average (channel-major layout: ears are the leading S-blocks)."""
        score = self.monaural_predictor(self._with_class_plane(torch.log1p(binaural), class_index))
        # (left + right) * 0.5 is bit-identical to a mean over the ears and, unlike a reduction over a
        # reshaped channel axis, costs no copy in channels_last.
        monos = self.config.monaural_channels
        ear_mean = (binaural[:, :monos] + binaural[:, monos:]) * 0.5
        return F.softplus(score) * _INV_LN2 * ear_mean

    def refine(self, monaural: torch.Tensor, memory: torch.Tensor | None,
               reset: torch.Tensor | None = None) -> torch.Tensor:
        """f^R: fuse the current estimate with the memory; ``memory=None`` or ``reset[b]`` starts afresh."""
        if memory is None:
            previous = monaural
        else:
            if memory.shape != monaural.shape:
                raise AudioError(f"memory shape {tuple(memory.shape)} differs from estimate {tuple(monaural.shape)}")
            previous = memory if reset is None else torch.where(reset.reshape(-1, 1, 1, 1), monaural, memory)
        return F.relu(monaural + self.refiner(monaural, previous))

    def forward(self, mixture: torch.Tensor, class_index: torch.Tensor, memory: torch.Tensor | None = None,
                reset: torch.Tensor | None = None) -> SeparatorStep:
        mask, binaural = self.separate_binaural(mixture, class_index)
        monaural = self.predict_monaural(binaural, class_index)
        return SeparatorStep(mask, binaural, monaural, self.refine(monaural, memory, reset))


def count_parameters(module: nn.Module) -> int:
    return sum(p.numel() for p in module.parameters())


@dataclass(frozen=True)
class ClipSeparation:
    """Result of :func:`separate_clip` (numpy outputs, torch memory)."""

    magnitude: np.ndarray  # (B, F, T) refined monaural magnitude, float32
    waveform: np.ndarray  # (B, N) mixture-phase reconstruction, float32
    memory: torch.Tensor  # (B, S, H, W) refined estimate to pass to the next step


def network_input(spec: np.ndarray, *, n_slices: int = DEFAULT_STFT.n_freq_slices) -> torch.Tensor:
    """The networks' input for a complex spectrogram (B, C, F, T): ``to_slices(|spec|)``, (B, C * n_slices,
    F // n_slices, T) float32, as a channels_last CPU tensor (the layout the fused convolutions compute
    in), written in one pass: no separate magnitude, slicing copy and layout conversion."""
    batch, channels, n_freq, n_frames = spec.shape
    height = n_freq // n_slices
    out = np.empty((batch, height, n_frames, channels, n_slices), dtype=np.float32)
    np.abs(spec.reshape(batch, channels, n_slices, height, n_frames).transpose(0, 3, 4, 1, 2), out=out)
    return torch.from_numpy(out).reshape(batch, height, n_frames, channels * n_slices).permute(0, 3, 1, 2)


def separate_clip(separator: Separator, binaural: np.ndarray, class_index: int | np.ndarray, *,
                  memory: torch.Tensor | None = None, reset: np.ndarray | None = None,
                  config: StftConfig = DEFAULT_STFT) -> ClipSeparation:
    """Binaural waveform (B, 2, N) + class index -> target's monaural magnitude and waveform.

    numpy -> torch happens once, on the sliced mixture magnitude (after the core STFT); torch -> numpy
    once, on the refined estimate (before un-slicing and the mixture-phase inverse STFT). The memory
    stays a tensor on the separator's device. Runs under ``torch.inference_mode()`` (so the memory is
    an inference tensor: pass it back here, do not train on it); call ``separator.eval()`` first, or
    pass ``models.inference.fuse_for_inference(separator)`` for the fast path (same numbers). The
    network input is channels_last, the layout the fused convolutions compute in; the caller picks
    the torch thread count (``models.threads.inference_threads``).
    """
    mixture = np.asarray(binaural, dtype=np.float32)
    if mixture.ndim != 3 or mixture.shape[1] != N_EARS:
        raise AudioError(f"binaural waveform must be (B, {N_EARS}, N), got {mixture.shape}")
    separator.config.check_stft(config)
    spec = stft(mixture, config=config)  # (B, 2, F, T) complex64
    device = next(separator.parameters()).device
    sliced = network_input(spec, n_slices=config.n_freq_slices)
    classes = torch.as_tensor(np.broadcast_to(np.asarray(class_index), (mixture.shape[0],)).copy(), device=device)
    reset_t = None if reset is None else torch.as_tensor(np.asarray(reset, dtype=bool), device=device)
    with torch.inference_mode():
        step = separator(sliced.to(device), classes, memory, reset_t)
    refined = step.refined.cpu().numpy()
    magnitude = from_slices(refined, n_slices=config.n_freq_slices)[:, 0]  # (B, F, T)
    ear_mean = (spec[:, 0] + spec[:, 1]) * 0.5  # = spec.mean(axis=1) bit for bit, without the slow complex reduction
    waveform = rebuild_with_phase(magnitude, ear_mean, config=config, length=mixture.shape[-1])
    return ClipSeparation(magnitude, waveform, step.refined)
