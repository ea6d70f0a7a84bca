"""Self-describing checkpoints: the file says what model it holds and how to rebuild it.

A checkpoint is a ``torch.save``-d dict of plain types (loaded with ``weights_only=True``):

  format       int, CHECKPOINT_FORMAT
  kind         str, e.g. SEPARATOR_KIND
  model_args   dict, the model's configuration dataclass as a dict
  state_dict   dict[str, Tensor]
  metadata     dict of JSON-like values (training run, data, seed, ...)
  + kind-specific entries; separators add ``stft`` (StftConfig as a dict), ``classes`` (list[str])
    and ``separator_version`` (int, SEPARATOR_VERSION: what the outputs of the weights mean; absent
    in files written before it existed, which are version 1).

Files are written 0644 less the umask (as ``open`` would create them), not mkstemp's 0600.

Every problem (missing or corrupt file, wrong kind, settings or tensor shapes that differ from what
the caller expects) raises CheckpointError with a message naming the file and what differs.
"""

from __future__ import annotations

import json
import os
import tempfile
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import torch
from torch import nn

from m2h_ros.core.audio.stft import DEFAULT_STFT, StftConfig
from m2h_ros.errors import CheckpointError, ConfigError
from m2h_ros.models.separator import SEPARATOR_VERSION, Separator, SeparatorConfig
from m2h_ros.paths import PACKAGE_DIR

CHECKPOINT_FORMAT = 1
SEPARATOR_KIND = "m2h_separator"
# f^B, f^M and f^R pretrained passively: what pi^Q and pi^N trained against, and the f^R stage's start.
PRETRAINED_SEPARATOR_CHECKPOINT = PACKAGE_DIR / "models" / "default" / "separator_compact_pretrained.pt"
# The pretrained one with f^R trained beside the shipped pi^Q (the original's formulation): what the nodes,
# the main job and the evaluations run.
DEFAULT_SEPARATOR_CHECKPOINT = PACKAGE_DIR / "models" / "default" / "separator_compact.pt"
# The entry points that write them (named in error messages).
PRETRAINED_SEPARATOR_BUILD_COMMAND = "python -m m2h_ros.training.pretrain_separator"
DEFAULT_SEPARATOR_BUILD_COMMAND = (f"{PRETRAINED_SEPARATOR_BUILD_COMMAND}, then scripts/train_shipped.sh refiner "
                                   "(f^R trained beside pi^Q; docs/design/policies.md)")

_PLAIN_TYPES = (str, int, float, bool, type(None))


def _check_plain(value: Any, where: str) -> None:
    """Metadata must survive ``torch.load(weights_only=True)``: JSON-like values only. Types are
    checked exactly: subclasses (numpy.float64, torch's TorchVersion str) pickle as their own class,
    which the weights-only unpickler refuses."""
    if type(value) in _PLAIN_TYPES:
        return
    if type(value) in (list, tuple):
        for i, item in enumerate(value):
            _check_plain(item, f"{where}[{i}]")
        return
    if type(value) is dict:
        for key, item in value.items():
            if type(key) is not str:
                raise ConfigError(f"checkpoint {where} has a non-string key {key!r}")
            _check_plain(item, f"{where}.{key}")
        return
    raise ConfigError(f"checkpoint {where} holds a {type(value).__name__}; use str/int/float/bool/list/dict")


def write_checkpoint(path: str | os.PathLike, *, kind: str, model_args: Mapping[str, Any],
                     state_dict: Mapping[str, torch.Tensor], metadata: Mapping[str, Any] | None = None,
                     **extra: Any) -> Path:
    """Write a checkpoint atomically (temporary file + rename); returns the path."""
    payload = {"format": CHECKPOINT_FORMAT, "kind": kind, "model_args": dict(model_args),
               "metadata": dict(metadata or {}), **extra}
    _check_plain(payload, "checkpoint")
    payload["state_dict"] = {name: tensor.detach().cpu() for name, tensor in state_dict.items()}
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=path.name, suffix=".tmp", dir=path.parent)
    os.close(fd)
    try:
        torch.save(payload, tmp)
        os.chmod(tmp, 0o644 & ~_umask())
        os.replace(tmp, path)
    finally:
        if os.path.exists(tmp):
            os.unlink(tmp)
    return path


def _umask() -> int:
    """The process umask (reading it means setting it; restored at once)."""
    mask = os.umask(0o022)
    os.umask(mask)
    return mask


def require_entries(payload: dict[str, Any], path: Path, keys: tuple[str, ...]) -> None:
    for key in keys:
        if key not in payload:
            raise CheckpointError(f"checkpoint {path} lacks the entry {key!r}")


def model_settings(payload: dict[str, Any], path: Path, config_type):
    """(model config, STFT config) of a checkpoint, checked against each other; CheckpointError if not."""
    try:
        config = config_type.from_dict(payload["model_args"])
        stft_config = StftConfig.from_dict(payload["stft"])
        config.check_stft(stft_config)
    except (ConfigError, TypeError) as exc:
        raise CheckpointError(f"checkpoint {path} has invalid settings: {exc}") from exc
    return config, stft_config


def read_checkpoint(path: str | os.PathLike, *, kind: str, map_location: str | torch.device = "cpu") -> dict[str, Any]:
    """Load and check the envelope of a checkpoint of the given kind."""
    path = Path(path)
    if not path.is_file():
        raise CheckpointError(f"checkpoint {path} not found")
    try:
        payload = torch.load(path, map_location=map_location, weights_only=True)
    except Exception as exc:  # torch raises many types for truncated / foreign files
        raise CheckpointError(f"checkpoint {path} is corrupt or not a torch checkpoint: {exc}") from exc
    if not isinstance(payload, dict):
        raise CheckpointError(f"checkpoint {path} holds a {type(payload).__name__}, not a checkpoint dict")
    for key in ("format", "kind", "model_args", "state_dict", "metadata"):
        if key not in payload:
            raise CheckpointError(f"checkpoint {path} lacks the entry {key!r}")
    if payload["format"] != CHECKPOINT_FORMAT:
        raise CheckpointError(f"checkpoint {path} has format {payload['format']}, this code reads {CHECKPOINT_FORMAT}")
    if payload["kind"] != kind:
        raise CheckpointError(f"checkpoint {path} holds a {payload['kind']!r} model, expected {kind!r}")
    return payload


def _differences(prefix: str, found: Mapping[str, Any], expected: Mapping[str, Any]) -> list[str]:
    return [f"{prefix}.{key} is {found.get(key)!r}, expected {expected.get(key)!r}"
            for key in sorted(set(found) | set(expected)) if found.get(key) != expected.get(key)]


def load_state_checked(module: nn.Module, state_dict: Mapping[str, torch.Tensor], *, path: Path) -> None:
    """``load_state_dict`` with a CheckpointError naming missing/unexpected tensors and shape changes."""
    own = module.state_dict()
    problems = [f"missing {name}" for name in own if name not in state_dict]
    problems += [f"unexpected {name}" for name in state_dict if name not in own]
    problems += [f"{name} has shape {tuple(state_dict[name].shape)}, model expects {tuple(t.shape)}"
                 for name, t in own.items() if name in state_dict and state_dict[name].shape != t.shape]
    if problems:
        shown = "; ".join(problems[:5]) + (f"; and {len(problems) - 5} more" if len(problems) > 5 else "")
        raise CheckpointError(f"checkpoint {path} does not fit the model: {shown}")
    module.load_state_dict(state_dict)


def class_index_in(classes: Sequence[str], name: str, *, model: str) -> int:
    """Index of a target class in a checkpoint's class list; ConfigError naming the known ones."""
    if name not in classes:
        raise ConfigError(f"unknown target class {name!r}; this {model} knows {list(classes)}")
    return list(classes).index(name)


@dataclass(frozen=True)
class LoadedSeparator:
    """A separator rebuilt from its checkpoint (in eval mode) with the settings it was trained with."""

    separator: Separator
    config: SeparatorConfig
    stft: StftConfig
    classes: tuple[str, ...]
    path: Path
    metadata: dict[str, Any] = field(default_factory=dict)

    def class_index(self, name: str) -> int:
        return class_index_in(self.classes, name, model="separator")


def save_separator(path: str | os.PathLike, separator: Separator, *, classes: Sequence[str],
                   stft_config: StftConfig = DEFAULT_STFT, metadata: Mapping[str, Any] | None = None,
                   metadata_json: bool = False) -> Path:
    """Save a separator with its model args, STFT settings, target classes and training metadata;
    ``metadata_json``: the metadata also beside it as ``<stem>.json`` (readable without torch)."""
    classes = list(classes)
    if not classes or len(set(classes)) != len(classes) or not all(isinstance(c, str) and c for c in classes):
        raise ConfigError(f"separator classes must be distinct non-empty names, got {classes!r}")
    separator.config.check_stft(stft_config)
    saved = write_checkpoint(path, kind=SEPARATOR_KIND, model_args=separator.config.to_dict(),
                             state_dict=separator.state_dict(), metadata=metadata,
                             stft=stft_config.to_dict(), classes=classes, separator_version=SEPARATOR_VERSION)
    if metadata_json:
        saved.with_suffix(".json").write_text(json.dumps(dict(metadata or {}), indent=1) + "\n")
    return saved


def load_separator(path: str | os.PathLike, *, expected_config: SeparatorConfig | None = None,
                   expected_stft: StftConfig | None = None, expected_classes: Sequence[str] | None = None,
                   map_location: str | torch.device = "cpu") -> LoadedSeparator:
    """Rebuild a Separator from ``path``; ``expected_*`` (when given) must match the stored settings."""
    path = Path(path)
    shipped = {DEFAULT_SEPARATOR_CHECKPOINT.resolve(): DEFAULT_SEPARATOR_BUILD_COMMAND,
               PRETRAINED_SEPARATOR_CHECKPOINT.resolve(): PRETRAINED_SEPARATOR_BUILD_COMMAND}
    if not path.is_file() and path.resolve() in shipped:
        raise CheckpointError(f"shipped separator checkpoint {path} not found; build it with "
                              f"`{shipped[path.resolve()]}`")
    payload = read_checkpoint(path, kind=SEPARATOR_KIND, map_location=map_location)
    require_entries(payload, path, ("stft", "classes"))
    version = payload.get("separator_version", 1)
    if version != SEPARATOR_VERSION:
        raise CheckpointError(f"checkpoint {path} holds a version-{version} separator (other output "
                              f"parameterisation), this code needs version {SEPARATOR_VERSION}; retrain it with "
                              f"`{PRETRAINED_SEPARATOR_BUILD_COMMAND} --out {path}`")
    config, stft_config = model_settings(payload, path, SeparatorConfig)
    classes = tuple(payload["classes"])
    problems: list[str] = []
    if expected_config is not None:
        problems += _differences("model_args", config.to_dict(), expected_config.to_dict())
    if expected_stft is not None:
        problems += _differences("stft", stft_config.to_dict(), expected_stft.to_dict())
    if expected_classes is not None and classes != tuple(expected_classes):
        problems.append(f"classes are {list(classes)}, expected {list(expected_classes)}")
    if problems:
        raise CheckpointError(f"checkpoint {path} settings differ: " + "; ".join(problems))
    separator = Separator(config)
    load_state_checked(separator, payload["state_dict"], path=path)
    separator.to(map_location).eval()
    return LoadedSeparator(separator, config, stft_config, classes, path, payload["metadata"])
