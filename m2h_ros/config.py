"""Validated, frozen configuration dataclasses.

One dataclass per node (see ``node_configs``). Each field carries its description and allowed range
in its metadata, so ``ros/params.py`` can declare it as a ROS parameter and the same YAML in
``params/`` loads into it for training and offline use.
"""

import dataclasses
import difflib
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


def unknown_names(unknown: Sequence[str], known: Sequence[str]) -> str:
    """``unknown`` names, each with the known name nearest to it: a typo names its fix."""
    parts = []
    for name in unknown:
        close = difflib.get_close_matches(name, known, n=1, cutoff=0.6)
        parts.append(f"{name} (did you mean {close[0]}?)" if close else name)
    return ", ".join(parts)


def typed_value(cls: type, name: str, text: str) -> Any:
    """``text`` (as typed on a command line: ``name:=text``) as the type of field ``name`` of ``cls``:
    read as YAML, as ROS reads a parameter's value; ConfigError for text of another type."""
    kind = get_type_hints(cls)[name]
    if kind is str:
        return text  # a path of digits stays a string
    try:
        value = yaml.safe_load(text)
    except yaml.YAMLError:
        value = text
    if kind is float and type(value) is int:
        return float(value)
    item = kind.__args__[0] if getattr(kind, "__origin__", None) is tuple else None
    if item is not None and isinstance(value, list) and all(type(v) is item for v in value):
        return tuple(value)
    if type(value) is not kind:
        raise ConfigError(f"{cls.__name__}.{name} = {text!r}: expected {_KIND_NAMES.get(kind, 'a list')}")
    return value


def accepted_values(cls: type, f: dataclasses.Field) -> str:
    """What field ``f`` of ``cls`` accepts, for an error message: its choices, or its type and range."""
    meta = f.metadata
    if meta.get("choices"):
        return ", ".join(map(str, meta["choices"]))
    kind = get_type_hints(cls)[f.name]
    text = _KIND_NAMES.get(kind, f"a list [A,B,...] of {getattr(kind, '__args__', (str,))[0].__name__}")
    lo, hi = meta.get("min"), meta.get("max")
    if lo is not None and hi is not None:
        return f"{text} from {lo} to {hi}"
    if lo is not None or hi is not None:
        return f"{text} {'>=' if lo is not None else '<='} {lo if lo is not None else hi}"
    return text


_KIND_NAMES = {bool: "true or false", int: "an integer", float: "a number", str: "text"}


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
            raise ConfigError(f"unknown {cls.__name__} setting(s){where}: {unknown_names(unknown, sorted(names))}; "
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
