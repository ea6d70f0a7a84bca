"""Validated, frozen configuration dataclasses.

One dataclass per node (see ``node_configs``). Each field carries its description and allowed range
in its metadata, so ``ros/params.py`` can declare it as a ROS parameter and the same YAML in
``params/`` loads into it for training and offline use.
"""

import dataclasses
import math
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any, get_type_hints

import yaml

from m2h_ros.errors import ConfigError

SCALAR_TYPES = (bool, int, float, str)
DEVICES = ("auto", "cpu", "cuda")  # torch devices a run may ask for; auto: CUDA when present, else the CPU


def reject_unknown_fields(cls: type, values: Mapping[str, Any]) -> None:
    """ConfigError naming the keys of ``values`` that are not fields of dataclass ``cls``."""
    unknown = set(values) - {f.name for f in dataclasses.fields(cls)}
    if unknown:
        raise ConfigError(f"{cls.__name__} has no field(s) {sorted(unknown)}")


def check_int_fields(config: Any, minimums: Sequence[tuple[str, int]]) -> None:
    """ConfigError unless each named field of ``config`` is an int (not a bool) >= its minimum."""
    for name, low in minimums:
        value = getattr(config, name)
        if isinstance(value, bool) or not isinstance(value, int) or value < low:
            raise ConfigError(f"{type(config).__name__}.{name} must be an int >= {low}, got {value!r}")


def setting(default: Any, description: str, *, min: float | None = None, max: float | None = None,
            choices: tuple | None = None) -> Any:
    """A dataclass field with a description and an optional inclusive range or set of choices."""
    meta = {"description": description, "min": min, "max": max, "choices": choices}
    if isinstance(default, list | dict):
        raise TypeError("use a tuple for sequence defaults: configs are immutable")
    return dataclasses.field(default=default, metadata=meta)


class Config:
    """Mixin for frozen dataclasses of settings: type, range and choice checks in __post_init__."""

    def __post_init__(self) -> None:
        hints = get_type_hints(type(self))
        for f in dataclasses.fields(self):
            value = getattr(self, f.name)
            kind = hints[f.name]
            where = f"{type(self).__name__}.{f.name} = {value!r}"
            if kind is float and isinstance(value, int) and not isinstance(value, bool):
                object.__setattr__(self, f.name, float(value))  # YAML/CLI users write 1 for 1.0
                value = float(value)
            if kind in SCALAR_TYPES:
                if type(value) is not kind:
                    raise ConfigError(f"{where}: expected {kind.__name__}")
                if kind is float and not math.isfinite(value):
                    raise ConfigError(f"{where}: must be finite")
            elif getattr(kind, "__origin__", None) is tuple:
                if isinstance(value, list):
                    value = tuple(value)
                    object.__setattr__(self, f.name, value)
                item = kind.__args__[0]
                if not isinstance(value, tuple) or not all(type(v) is item for v in value):
                    raise ConfigError(f"{where}: expected a list of {item.__name__}")
            lo, hi, choices = f.metadata.get("min"), f.metadata.get("max"), f.metadata.get("choices")
            if lo is not None and value < lo:
                raise ConfigError(f"{where}: must be >= {lo}")
            if hi is not None and value > hi:
                raise ConfigError(f"{where}: must be <= {hi}")
            if choices is not None and value not in choices:
                raise ConfigError(f"{where}: must be one of {', '.join(map(repr, choices))}")

    @classmethod
    def from_dict(cls, values: Mapping[str, Any], *, source: str = "") -> "Config":
        names = {f.name for f in dataclasses.fields(cls)}
        unknown = sorted(set(values) - names)
        if unknown:
            where = f" in {source}" if source else ""
            raise ConfigError(f"unknown {cls.__name__} setting(s){where}: {', '.join(unknown)}; "
                              f"known: {', '.join(sorted(names))}")
        return cls(**values)

    @classmethod
    def from_yaml(cls, path: str | Path, node_name: str) -> "Config":
        """Load ``node_name: ros__parameters: {...}`` from a ROS 2 params file."""
        path = Path(path)
        try:
            document = yaml.safe_load(path.read_text()) or {}
        except (OSError, yaml.YAMLError) as exc:
            raise ConfigError(f"cannot read params file {path}: {exc}") from exc
        section = document.get(node_name, document.get(f"/{node_name}"))
        if not isinstance(section, dict) or not isinstance(section.get("ros__parameters"), dict):
            raise ConfigError(f"{path} has no '{node_name}: ros__parameters:' section")
        return cls.from_dict(section["ros__parameters"], source=str(path))

    def replace(self, **changes: Any) -> "Config":
        return dataclasses.replace(self, **changes)
