"""The Move2Hear policy network (supplementary Sec. 7, and the original code's ``PolicyNet``) and the
learned baselines that share it (Novelty, AV Navigator); self-describing policy checkpoints.

Per step the network encodes what the robot observes, feeds the concatenated features to a GRU and
reads an action distribution (actor) and a value (critic) from the GRU's output:

* E^V over the camera's **RGB** (uint8 / 255). The paper's agent has RGB and depth sensors, but the
  original code encodes RGB only (``SENSORS: [RGB_SENSOR, DEPTH_SENSOR]`` with ``EXTRA_DEPTH: True``,
  which keeps depth out of the visual encoder); so does this one. Convs k 8, 4, 3, strides 4, 2, 1,
  channels 32, 64, 32 (ReLU), FC to ``hidden`` (ReLU). The image is area-averaged to
  ``image_size`` first (128: the original's 128 x 128; the compact preset 64).
* E^B over log(1 + f^B's separated binaural magnitude), E^M over log(1 + [f^M's monaural estimate,
  f^R's refined memory]); both in the sliced layout (2 x 16 channels of 32 x 32) and the same CNN
  with last kernel 2 (``inputs="separation"``: Move2Hear pi^Q / pi^N, Novelty).
* AV Navigator (``inputs="mixture"``): one such audio encoder over log(1 + |mixture|) (32 channels)
  plus the constant target-class plane (:func:`m2h_ros.core.audio.stft.class_channel_value`).
* A one-layer **unidirectional** GRU of ``hidden`` units (orthogonal weights, zero biases, as the
  original's ``RNNStateEncoder``). The seed text calls it bidirectional; a policy that acts step by
  step cannot read the future, and the original's ``nn.GRU`` is unidirectional.
* Actor and critic: one linear layer each, initialised as the original (orthogonal; gain 0.01 for
  the actor, so the untrained policy is near-uniform). Convs and FCs: Kaiming-normal, zero biases.

Actions: with ``stop`` the network chooses among STOP, MOVE_FORWARD, TURN_LEFT, TURN_RIGHT (pi^N,
AV Navigator); without it among the three moves (pi^Q and Novelty, as the original's near-target
action space): :meth:`PolicyConfig.env_actions` maps network outputs to environment actions.
"""

from __future__ import annotations

import os
from dataclasses import asdict, dataclass, field, fields, replace
from pathlib import Path
from typing import Any, NamedTuple

import numpy as np
import torch
from torch import nn

from m2h_ros.core.audio.stft import DEFAULT_STFT, StftConfig, class_channel_value, stft, to_slices
from m2h_ros.core.world.episodes import MOVE_FORWARD, STOP, TURN_LEFT, TURN_RIGHT
from m2h_ros.config import reject_unknown_fields
from m2h_ros.errors import CheckpointError, ConfigError
from m2h_ros.models.checkpoint import (load_state_checked, model_settings, read_checkpoint, require_entries,
                                       write_checkpoint)

POLICY_KIND = "m2h_policy"
PRESET_NAMES = ("paper", "compact")
INPUTS = ("separation", "mixture")
VISUAL_KERNELS, AUDIO_KERNELS, STRIDES = (8, 4, 3), (8, 4, 2), (4, 2, 1)
ACTIONS_WITH_STOP = (STOP, MOVE_FORWARD, TURN_LEFT, TURN_RIGHT)
ACTIONS_NO_STOP = (MOVE_FORWARD, TURN_LEFT, TURN_RIGHT)


def _positive_int(value: Any) -> bool:
    return isinstance(value, int) and not isinstance(value, bool) and value > 0


@dataclass(frozen=True)
class PolicyConfig:
    """Model arguments of :class:`PolicyNet` (stored in checkpoints as a dict)."""

    inputs: str = "separation"  # "separation" (E^B + E^M) | "mixture" (AV Navigator's E^A)
    stop: bool = False  # whether STOP is one of the actions
    camera: bool = True  # E^V over RGB
    hidden: int = 512  # encoder FC width and GRU size
    channels: tuple[int, ...] = (32, 64, 32)  # conv widths of every encoder
    image_size: int = 128  # RGB is area-averaged to image_size x image_size
    n_freq_slices: int = DEFAULT_STFT.n_freq_slices
    slice_shape: tuple[int, ...] = DEFAULT_STFT.slice_shape  # (height, width) of a sliced plane

    def __post_init__(self) -> None:
        if self.inputs not in INPUTS:
            raise ConfigError(f"PolicyConfig.inputs={self.inputs!r} must be one of {INPUTS}")
        for name in ("stop", "camera"):
            if not isinstance(getattr(self, name), bool):
                raise ConfigError(f"PolicyConfig.{name}={getattr(self, name)!r} must be a bool")
        for name, length in (("channels", 3), ("slice_shape", 2)):
            value = tuple(getattr(self, name)) if isinstance(getattr(self, name), (list, tuple)) else ()
            if len(value) != length or not all(_positive_int(v) for v in value):
                raise ConfigError(f"PolicyConfig.{name} must be {length} positive ints, got {getattr(self, name)!r}")
            object.__setattr__(self, name, value)
        for name in ("hidden", "image_size", "n_freq_slices"):
            if not _positive_int(getattr(self, name)):
                raise ConfigError(f"PolicyConfig.{name} must be a positive int, got {getattr(self, name)!r}")
        for name, size, kernels in (("image_size", (self.image_size,) * 2, VISUAL_KERNELS),
                                    ("slice_shape", self.slice_shape, AUDIO_KERNELS)):
            if min(_conv_output(size, kernels)) < 1:
                raise ConfigError(f"PolicyConfig.{name}={size} is too small for kernels {kernels}, strides {STRIDES}")

    @classmethod
    def preset(cls, name: str, *, inputs: str = "separation", stop: bool = False, camera: bool = True) -> PolicyConfig:
        """``paper``: the published widths (FC/GRU 512, convs 32, 64, 32, RGB 128 x 128);
        ``compact``: a CPU-training width (FC/GRU 128, convs 16, 32, 16, RGB 64 x 64)."""
        if name == "paper":
            return cls(inputs=inputs, stop=stop, camera=camera)
        if name == "compact":
            return cls(inputs=inputs, stop=stop, camera=camera, hidden=128, channels=(16, 32, 16), image_size=64)
        raise ConfigError(f"unknown policy preset {name!r}; choose one of {PRESET_NAMES}")

    @property
    def n_actions(self) -> int:
        return len(self.env_actions())

    def env_actions(self) -> np.ndarray:
        """Environment action of each network output."""
        return np.array(ACTIONS_WITH_STOP if self.stop else ACTIONS_NO_STOP, np.int64)

    def check_stft(self, stft_config: StftConfig) -> None:
        if (stft_config.n_freq_slices, stft_config.slice_shape) != (self.n_freq_slices, self.slice_shape):
            raise ConfigError(f"the STFT gives {stft_config.n_freq_slices} slices of {stft_config.slice_shape}, "
                              f"the policy expects {self.n_freq_slices} of {self.slice_shape}")

    def to_dict(self) -> dict[str, Any]:
        values = asdict(self)
        values["channels"], values["slice_shape"] = list(self.channels), list(self.slice_shape)
        return values

    @classmethod
    def from_dict(cls, values: dict[str, Any]) -> PolicyConfig:
        reject_unknown_fields(cls, values)
        return cls(**values)


def _conv_output(size: tuple[int, ...], kernels: tuple[int, ...]) -> tuple[int, ...]:
    for kernel, stride in zip(kernels, STRIDES, strict=True):
        size = tuple((s - kernel) // stride + 1 for s in size)
    return size


class PolicyInputs(NamedTuple):
    """One batch of network inputs (leading dim N; None where the configuration has no such input)."""

    rgb: torch.Tensor | None  # (N, 3, s, s) uint8, area-averaged to image_size
    audio: torch.Tensor  # (N, 2S, H, W) log(1 + separated binaural) | (N, 2S + 1, H, W) mixture + class
    monaural: torch.Tensor | None  # (N, 2S, H, W) log(1 + [f^M estimate, f^R memory]) (separation only)

    def to(self, device: torch.device | str) -> PolicyInputs:
        return PolicyInputs(*(None if t is None else t.to(device) for t in self))

    def flat(self) -> PolicyInputs:
        """(T, N, ...) -> (T * N, ...)."""
        return PolicyInputs(*(None if t is None else t.flatten(0, 1) for t in self))

    def index(self, rows) -> PolicyInputs:
        return PolicyInputs(*(None if t is None else t[rows] for t in self))


def area_downsample(rgb: np.ndarray, size: int) -> torch.Tensor:
    """(N, H, W, 3) uint8 -> (N, 3, size, size) uint8, averaging whole blocks of pixels."""
    n, height, width, _ = rgb.shape
    if height % size or width % size:
        raise ConfigError(f"camera images of {height} x {width} do not average down to {size} x {size}; "
                          f"use a camera size that is a multiple of the policy's image_size")
    image = torch.from_numpy(np.ascontiguousarray(rgb))
    if height == width == size:
        return image.permute(0, 3, 1, 2).clone(memory_format=torch.channels_last)  # a copy; the view's layout
    # Block sums by whole-slab adds in the (N, H, W, 3) layout, then / block area and round: what
    # avg_pool2d gives bit for bit (sums of integers in float32 are exact in any order), 3x faster
    # than it on the permuted view. The result is channels_last, the encoders' layout.
    rows, cols = height // size, width // size
    blocks = image.float().view(n * size, rows, size, cols, 3)
    total = blocks[:, 0].clone()
    for i in range(1, rows):
        total += blocks[:, i]
    pooled = total[:, :, 0].clone()
    for j in range(1, cols):
        pooled += total[:, :, j]
    return pooled.div_(rows * cols).round_().to(torch.uint8).view(n, size, size, 3).permute(0, 3, 1, 2)


def policy_inputs(config: PolicyConfig, *, separated_binaural: np.ndarray, monaural: np.ndarray,
                  refined: np.ndarray, audio: np.ndarray, target_class: np.ndarray, rgb: np.ndarray | None,
                  stft_config: StftConfig = DEFAULT_STFT, out: PolicyInputs | None = None) -> PolicyInputs:
    """The network inputs of B slots from what a controller observes (numpy, (F, T) layouts as in
    :class:`m2h_ros.agents.base.ControllerObservation`); ``target_class`` (B,) indices of
    ``TARGET_CATEGORIES``. Training and the controllers both call this (or, with the separator's own
    tensors, :func:`sliced_policy_inputs`), so they feed the same numbers. ``out``: channels_last
    tensors to write the inputs into (rows of :func:`policy_input_buffers`)."""
    s = config.n_freq_slices

    def sliced(x: np.ndarray) -> torch.Tensor:
        return torch.from_numpy(to_slices(np.asarray(x, np.float32), n_slices=s))

    if config.inputs == "separation":
        return sliced_policy_inputs(config, binaural=sliced(separated_binaural), monaural=sliced(monaural[:, None]),
                                    refined=sliced(refined[:, None]), rgb=rgb, out=out)
    out = out or PolicyInputs(None, None, None)
    spectrum = torch.from_numpy(to_slices(np.abs(stft(np.asarray(audio, np.float32), config=stft_config)), n_slices=s))
    audio_in = _log1p_into((spectrum,), _output(out.audio, (len(spectrum), 2 * s + 1, *spectrum.shape[-2:])), extra=1)
    audio_in[:, 2 * s:] = torch.from_numpy(class_channel_value(np.asarray(target_class))).reshape(-1, 1, 1, 1)
    return PolicyInputs(_rgb_input(config, rgb, out.rgb), audio_in, None)


def sliced_policy_inputs(config: PolicyConfig, *, binaural: torch.Tensor, monaural: torch.Tensor,
                         refined: torch.Tensor, rgb: np.ndarray | None, out: PolicyInputs | None = None) -> PolicyInputs:
    """:func:`policy_inputs` of a separation policy from the separator's sliced tensors (f^B (B, 2S, H, W),
    f^M and f^R (B, S, H, W): ``SeparationStep.sliced``), the same numbers without the (F, T) arrays; in
    channels_last they go into the channels_last inputs without a transpose."""
    if config.inputs != "separation":
        raise ConfigError(f"sliced_policy_inputs feeds separation policies, not {config.inputs!r} ones")
    out = out or PolicyInputs(None, None, None)
    audio_in = _log1p_into((binaural,), _output(out.audio, binaural.shape))
    mono_in = _log1p_into((monaural, refined), _output(out.monaural, (len(monaural), 2 * monaural.shape[1],
                                                                       *monaural.shape[2:])))
    return PolicyInputs(_rgb_input(config, rgb, out.rgb), audio_in, mono_in)


def _output(out: torch.Tensor | None, shape: tuple[int, ...]) -> torch.Tensor:
    return torch.empty(shape, memory_format=torch.channels_last) if out is None else out


def _log1p_into(parts: tuple[torch.Tensor, ...], out: torch.Tensor, *, extra: int = 0) -> torch.Tensor:
    """log(1 + max(x, 0)) of the channel concatenation of ``parts`` (N, C_i, H, W), written into the first
    channels of ``out`` (``extra`` channels after them are left to the caller). Elementwise, so the
    numbers do not depend on the layouts; torch's float32 log1p is several times numpy's speed."""
    first = 0
    for part in parts:
        torch.clamp_min(part, 0.0, out=out[:, first: first + part.shape[1]])
        first += part.shape[1]
    if first + extra != out.shape[1]:
        raise ConfigError(f"{first} + {extra} input channels for an output of {out.shape[1]}")
    out[:, :first].log1p_()
    return out


def _rgb_input(config: PolicyConfig, rgb: np.ndarray | None, out: torch.Tensor | None) -> torch.Tensor | None:
    if not config.camera:
        return None
    if rgb is None:
        raise ConfigError("this policy encodes the camera's RGB, but the observation has none")
    image = area_downsample(np.asarray(rgb), config.image_size)
    return image if out is None else out.copy_(image)


def policy_input_buffers(config: PolicyConfig, *, steps: int, slots: int) -> PolicyInputs:
    """Uninitialised (steps, slots, C, H, W) tensors for a rollout's inputs (``policy_inputs(out=buffers.index(t))``),
    each (steps * slots, C, H, W) channels_last underneath, so ``flat()`` is a view the encoders take as is."""
    s, (h, w) = config.n_freq_slices, config.slice_shape

    def empty(channels: int, height: int, width: int, dtype: torch.dtype) -> torch.Tensor:
        flat = torch.empty((steps * slots, channels, height, width), dtype=dtype, memory_format=torch.channels_last)
        return flat.view(steps, slots, channels, height, width)

    separation = config.inputs == "separation"
    return PolicyInputs(empty(3, config.image_size, config.image_size, torch.uint8) if config.camera else None,
                        empty(2 * s if separation else 2 * s + 1, h, w, torch.float32),
                        empty(2 * s, h, w, torch.float32) if separation else None)


def _init_kaiming(module: nn.Module) -> None:
    for layer in module.modules():
        if isinstance(layer, (nn.Conv2d, nn.Linear)):
            nn.init.kaiming_normal_(layer.weight, nonlinearity="relu")
            nn.init.zeros_(layer.bias)


class ConvEncoder(nn.Module):
    """3 convs (ReLU) + FC (ReLU): (N, C, H, W) -> (N, hidden)."""

    def __init__(self, in_channels: int, size: tuple[int, ...], kernels: tuple[int, ...],
                 channels: tuple[int, ...], hidden: int) -> None:
        super().__init__()
        widths = (in_channels, *channels)
        layers: list[nn.Module] = []
        for i, (kernel, stride) in enumerate(zip(kernels, STRIDES, strict=True)):
            layers += [nn.Conv2d(widths[i], widths[i + 1], kernel_size=kernel, stride=stride), nn.ReLU(inplace=True)]
        out = _conv_output(size, kernels)
        layers += [nn.Flatten(), nn.Linear(channels[-1] * out[0] * out[1], hidden), nn.ReLU(inplace=True)]
        self.cnn = nn.Sequential(*layers)
        _init_kaiming(self.cnn)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        # channels_last sends the convolutions to oneDNN's direct kernels: the k8 s4 first layer over
        # 32 audio channels runs ~2.5x faster forward and backward than in NCHW on CPU (docs/design/policies.md,
        # Speed); the weights keep their layout, so checkpoints are unaffected. No copy if x already is.
        return self.cnn(x.contiguous(memory_format=torch.channels_last))


class PolicyStep(NamedTuple):
    logits: torch.Tensor  # (..., n_actions)
    value: torch.Tensor  # (...,)
    hidden: torch.Tensor  # (N, hidden) GRU state after the last step
    outputs: torch.Tensor  # (..., hidden) the GRU's output at each step (what actor and critic read)


class PolicyNet(nn.Module):
    """Encoders -> GRU -> actor / critic. ``step`` for acting, ``evaluate`` for a rollout sequence."""

    def __init__(self, config: PolicyConfig | None = None) -> None:
        super().__init__()
        self.config = config = config or PolicyConfig()
        s, size, c, h = config.n_freq_slices, config.slice_shape, config.channels, config.hidden
        n_features = 1
        self.visual_encoder = None
        if config.camera:
            self.visual_encoder = ConvEncoder(3, (config.image_size,) * 2, VISUAL_KERNELS, c, h)
            n_features += 1
        self.monaural_encoder = None
        if config.inputs == "separation":
            self.audio_encoder = ConvEncoder(2 * s, size, AUDIO_KERNELS, c, h)  # E^B
            self.monaural_encoder = ConvEncoder(2 * s, size, AUDIO_KERNELS, c, h)  # E^M
            n_features += 1
        else:
            self.audio_encoder = ConvEncoder(2 * s + 1, size, AUDIO_KERNELS, c, h)  # mixture + class
        self.gru = nn.GRU(n_features * h, h, num_layers=1)
        for name, param in self.gru.named_parameters():
            (nn.init.orthogonal_ if "weight" in name else nn.init.zeros_)(param)
        self.actor = nn.Linear(h, config.n_actions)
        self.critic = nn.Linear(h, 1)
        nn.init.orthogonal_(self.actor.weight, gain=0.01)
        nn.init.orthogonal_(self.critic.weight)
        nn.init.zeros_(self.actor.bias)
        nn.init.zeros_(self.critic.bias)

    def initial_hidden(self, n: int) -> torch.Tensor:
        return torch.zeros(n, self.config.hidden, device=self.actor.weight.device)

    def features(self, inputs: PolicyInputs) -> torch.Tensor:
        """(N, n_features * hidden) encoder outputs."""
        parts = [self.audio_encoder(inputs.audio)]
        if self.monaural_encoder is not None:
            parts.append(self.monaural_encoder(inputs.monaural))
        if self.visual_encoder is not None:
            # A copy divided in place: one 16 MB temporary fewer per update pass than float() / 255.
            parts.append(self.visual_encoder(inputs.rgb.to(torch.float32, copy=True).div_(255.0)))
        return torch.cat(parts, dim=1)

    def _recur(self, features: torch.Tensor, hidden: torch.Tensor, starts: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """features (T, N, F), starts (T, N) bool (the GRU state is cleared there) -> (T, N, H), (N, H).

        The GRU runs over whole stretches of steps in which no slot starts an episode (one call, not
        one per step: the original's RNNStateEncoder does the same), clearing the state between them."""
        cuts = [0, *(torch.nonzero(starts[1:].any(dim=1))[:, 0] + 1).tolist(), features.shape[0]]
        outputs = []
        for first, end in zip(cuts[:-1], cuts[1:], strict=True):
            hidden = hidden * (~starts[first]).unsqueeze(1).to(hidden.dtype)
            out, h = self.gru(features[first:end], hidden.unsqueeze(0))
            hidden = h[0]
            outputs.append(out)
        return torch.cat(outputs), hidden

    def step(self, inputs: PolicyInputs, hidden: torch.Tensor, starts: torch.Tensor) -> PolicyStep:
        """One step of N slots: inputs (N, ...), hidden (N, H), starts (N,) bool."""
        out, hidden = self._recur(self.features(inputs).unsqueeze(0), hidden, starts.unsqueeze(0))
        return PolicyStep(self.actor(out[0]), self.critic(out[0])[:, 0], hidden, out[0])

    def evaluate(self, inputs: PolicyInputs, hidden: torch.Tensor, starts: torch.Tensor) -> PolicyStep:
        """A sequence: inputs (T * N, ...) time-major, hidden (N, H) before step 0, starts (T, N)."""
        t, n = starts.shape
        out, hidden = self._recur(self.features(inputs).reshape(t, n, -1), hidden, starts)
        return PolicyStep(self.actor(out), self.critic(out)[..., 0], hidden, out)


# --------------------------------------------------------------------------- checkpoints


@dataclass(frozen=True)
class LoadedPolicy:
    """A policy rebuilt from its checkpoint (eval mode) with what it was trained for."""

    net: PolicyNet
    config: PolicyConfig
    policy_kind: str  # the training kind: quality | navigation | approach | novelty | av_navigator
    stft: StftConfig
    path: Path
    metadata: dict[str, Any] = field(default_factory=dict)


def save_policy(path: str | os.PathLike, net: PolicyNet, *, policy_kind: str,
                stft_config: StftConfig = DEFAULT_STFT, metadata: dict[str, Any] | None = None) -> Path:
    net.config.check_stft(stft_config)
    return write_checkpoint(path, kind=POLICY_KIND, model_args=net.config.to_dict(), state_dict=net.state_dict(),
                            metadata=metadata, policy_kind=policy_kind, stft=stft_config.to_dict())


def load_policy(path: str | os.PathLike, *, policy_kind: str | None = None,
                map_location: str | torch.device = "cpu") -> LoadedPolicy:
    """Rebuild a PolicyNet from ``path``; ``policy_kind`` (when given) must be the one it was trained as."""
    path = Path(path)
    payload = read_checkpoint(path, kind=POLICY_KIND, map_location=map_location)
    require_entries(payload, path, ("policy_kind", "stft"))
    if policy_kind is not None and payload["policy_kind"] != policy_kind:
        raise CheckpointError(f"checkpoint {path} holds a {payload['policy_kind']!r} policy, expected {policy_kind!r}")
    config, stft_config = model_settings(payload, path, PolicyConfig)
    net = PolicyNet(config)
    load_state_checked(net, payload["state_dict"], path=path)
    net.to(map_location).eval()
    return LoadedPolicy(net, config, payload["policy_kind"], stft_config, path, payload["metadata"])


def warm_start(net: PolicyNet, source: LoadedPolicy) -> None:
    """Copy ``source``'s weights into ``net`` (training starts from them, not from random ones).

    Everything but the action space must match (inputs, camera, widths); the actor's rows are taken
    per environment action, so a pi^N + Stop checkpoint starts a pi^Q (no Stop) with its move logits,
    and a STOP row the source lacks keeps ``net``'s own initialisation."""
    ours, theirs = replace(net.config, stop=False), replace(source.config, stop=False)
    if ours != theirs:
        changed = [f.name for f in fields(PolicyConfig) if getattr(ours, f.name) != getattr(theirs, f.name)]
        raise ConfigError(f"cannot warm-start from {source.path}: its {', '.join(changed)} differ from this policy's")
    state = {k: v for k, v in source.net.state_dict().items() if not k.startswith("actor.")}
    source_rows = {int(a): i for i, a in enumerate(source.config.env_actions())}
    with torch.no_grad():
        net.load_state_dict(state, strict=False)
        for row, action in enumerate(net.config.env_actions()):
            if int(action) in source_rows:
                net.actor.weight[row] = source.net.actor.weight[source_rows[int(action)]]
                net.actor.bias[row] = source.net.actor.bias[source_rows[int(action)]]
