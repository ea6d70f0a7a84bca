"""The sound locator of the Gan et al. baseline: where the target is, and whether the robot is at it,
from one step of binaural audio (after Gan et al., "Look, Listen, and Act", ICRA 2020; the
Move2Hear paper's Sec. 5 baseline).

Input: log(1 + |STFT|) of the binaural mixture, averaged into ``bands`` equal frequency bands (the
level cues, interaural and spectral, survive; the fine structure a separator needs does not), plus
the constant target-class plane (:func:`m2h_ros.core.audio.stft.class_channel_value`), since the
mixture holds a distractor too. Three conv + max-pool blocks and one hidden layer feed two heads:

* ``offset``: the target's position relative to the robot, metres (forward, left) in its frame;
* ``stop_logit``: whether the robot stands on the target's node (the Stop predictor).

Checkpoints (kind ``m2h_locator``) carry the model arguments and STFT settings; the default one is
``m2h_ros/models/default/locator.pt`` (``scripts/train_locator.py``).
"""

from __future__ import annotations

import os
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any, NamedTuple

import numpy as np
import torch
from torch import nn

from m2h_ros.config import reject_unknown_fields
from m2h_ros.core.audio.stft import DEFAULT_STFT, StftConfig, class_channel_value, stft
from m2h_ros.errors import CheckpointError, ConfigError
from m2h_ros.models.checkpoint import (load_state_checked, model_settings, read_checkpoint, require_entries,
                                       write_checkpoint)
from m2h_ros.paths import PACKAGE_DIR

LOCATOR_KIND = "m2h_locator"
DEFAULT_LOCATOR_CHECKPOINT = PACKAGE_DIR / "models" / "default" / "locator.pt"
LOCATOR_BUILD_COMMAND = "python scripts/train_locator.py --out m2h_ros/models/default/locator.pt"


@dataclass(frozen=True)
class LocatorConfig:
    bands: int = 64  # frequency bands the 512 STFT bins are averaged into
    channels: tuple[int, ...] = (16, 32, 32)  # conv blocks (3x3 conv, ReLU, 2x2 max-pool)
    hidden: int = 128

    def __post_init__(self) -> None:
        if not (isinstance(self.bands, int) and self.bands >= 8):
            raise ConfigError(f"LocatorConfig.bands={self.bands!r} must be an int >= 8")
        if not (isinstance(self.hidden, int) and self.hidden >= 1):
            raise ConfigError(f"LocatorConfig.hidden={self.hidden!r} must be a positive int")
        channels = tuple(self.channels)
        if not channels or not all(isinstance(c, int) and c >= 1 for c in channels):
            raise ConfigError(f"LocatorConfig.channels={self.channels!r} must be positive ints")
        object.__setattr__(self, "channels", channels)

    def check_stft(self, config: StftConfig) -> None:
        if config.n_freq % self.bands:
            raise ConfigError(f"LocatorConfig.bands={self.bands} must divide the STFT's {config.n_freq} bins")
        if min(self.bands, config.n_frames) >> len(self.channels) < 1:
            raise ConfigError(f"{len(self.channels)} pooling blocks leave nothing of {self.bands} x {config.n_frames}")

    def to_dict(self) -> dict[str, Any]:
        return {**asdict(self), "channels": list(self.channels)}

    @classmethod
    def from_dict(cls, values: dict[str, Any]) -> LocatorConfig:
        reject_unknown_fields(cls, values)
        return cls(**{**values, "channels": tuple(values.get("channels", cls.channels))})


def locator_input(audio: np.ndarray, class_index: np.ndarray, *, bands: int,
                  config: StftConfig = DEFAULT_STFT) -> torch.Tensor:
    """(B, 2, N) binaural mixtures and (B,) target classes -> (B, 3, bands, T) network input."""
    magnitude = np.log1p(np.abs(stft(np.asarray(audio, np.float32), config=config)))  # (B, 2, F, T)
    b, _, f, t = magnitude.shape
    pooled = magnitude.reshape(b, 2, bands, f // bands, t).mean(axis=3)
    plane = np.broadcast_to(class_channel_value(np.asarray(class_index))[:, None, None, None], (b, 1, bands, t))
    return torch.from_numpy(np.concatenate([pooled, plane], axis=1).astype(np.float32))


def relative_offset(target_xy: np.ndarray, pose: np.ndarray) -> np.ndarray:
    """(B, 2) map positions and (B, 3) poses (x, y, yaw) -> (B, 2) (forward, left) in the robot frame:
    the locator's ``offset`` label."""
    d = np.asarray(target_xy, np.float64) - pose[:, :2]
    cos, sin = np.cos(pose[:, 2]), np.sin(pose[:, 2])
    return np.stack([d[:, 0] * cos + d[:, 1] * sin, -d[:, 0] * sin + d[:, 1] * cos], axis=1).astype(np.float32)


def map_position(offset: np.ndarray, pose: np.ndarray) -> np.ndarray:
    """The inverse of :func:`relative_offset`: (B, 2) (forward, left) offsets from (B, 3) poses -> (B, 2)
    map positions."""
    offset, pose = np.asarray(offset, np.float64), np.asarray(pose, np.float64)
    cos, sin = np.cos(pose[:, 2]), np.sin(pose[:, 2])
    return pose[:, :2] + np.stack([offset[:, 0] * cos - offset[:, 1] * sin,
                                   offset[:, 0] * sin + offset[:, 1] * cos], axis=1)


class LocatorOutput(NamedTuple):
    offset: torch.Tensor  # (B, 2) metres, (forward, left) in the robot's frame
    stop_logit: torch.Tensor  # (B,)


class SoundLocator(nn.Module):
    def __init__(self, config: LocatorConfig = LocatorConfig(), *, stft_config: StftConfig = DEFAULT_STFT) -> None:
        super().__init__()
        config.check_stft(stft_config)
        self.config = config
        layers: list[nn.Module] = []
        width = 3
        for out in config.channels:
            layers += [nn.Conv2d(width, out, 3, padding=1), nn.ReLU(inplace=True), nn.MaxPool2d(2)]
            width = out
        cells = (config.bands >> len(config.channels)) * (stft_config.n_frames >> len(config.channels))
        layers += [nn.Flatten(), nn.Linear(width * cells, config.hidden), nn.ReLU(inplace=True)]
        self.features = nn.Sequential(*layers)
        self.offset = nn.Linear(config.hidden, 2)
        self.stop = nn.Linear(config.hidden, 1)
        for layer in self.modules():
            if isinstance(layer, (nn.Conv2d, nn.Linear)):
                nn.init.kaiming_normal_(layer.weight, nonlinearity="relu")
                nn.init.zeros_(layer.bias)

    def forward(self, x: torch.Tensor) -> LocatorOutput:
        h = self.features(x)
        return LocatorOutput(self.offset(h), self.stop(h)[:, 0])


@dataclass(frozen=True)
class LoadedLocator:
    net: SoundLocator
    config: LocatorConfig
    stft: StftConfig
    path: Path
    metadata: dict[str, Any] = field(default_factory=dict)

    @torch.no_grad()
    def predict(self, audio: np.ndarray, class_index: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(B, 2, N) binaural mixtures and (B,) target classes -> ((B, 2) offsets in metres, forward and
        left in the robot's frame; (B,) probabilities that the robot stands on the target's node)."""
        out = self.net(locator_input(audio, class_index, bands=self.config.bands, config=self.stft))
        return out.offset.numpy(), torch.sigmoid(out.stop_logit).numpy()


def save_locator(path: str | os.PathLike, net: SoundLocator, *, stft_config: StftConfig = DEFAULT_STFT,
                 metadata: dict[str, Any] | None = None) -> Path:
    return write_checkpoint(path, kind=LOCATOR_KIND, model_args=net.config.to_dict(), state_dict=net.state_dict(),
                            metadata=metadata, stft=stft_config.to_dict())


def load_locator(path: str | os.PathLike = DEFAULT_LOCATOR_CHECKPOINT) -> LoadedLocator:
    path = Path(path)
    if not path.is_file():
        raise CheckpointError(f"sound locator checkpoint {path} not found; train it with `{LOCATOR_BUILD_COMMAND}`")
    payload = read_checkpoint(path, kind=LOCATOR_KIND)
    require_entries(payload, path, ("stft",))
    config, stft_config = model_settings(payload, path, LocatorConfig)
    net = SoundLocator(config, stft_config=stft_config)
    load_state_checked(net, payload["state_dict"], path=path)
    return LoadedLocator(net.eval(), config, stft_config, path, payload["metadata"])
