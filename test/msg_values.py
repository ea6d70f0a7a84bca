"""Deterministic, non-default values for every field of a message type, as plain nested dicts, plus
converters to rclpy and rosbags messages and back, so round trips can be compared field by field."""

import dataclasses
import importlib

import numpy as np
from rosbags.interfaces import Nodetype
from rosbags.typesys.store import Typestore

_INT_RANGES = {"int8": 127, "uint8": 255, "byte": 255, "char": 127, "int16": 32767,
               "uint16": 65535, "int32": 2**31 - 1, "uint32": 2**32 - 1,
               "int64": 2**63 - 1, "uint64": 2**64 - 1}
SEQUENCE_LENGTH = 5


def _base_value(typename: str, k: int):
    if typename == "bool":
        return k % 2 == 0
    if typename == "string":
        return f"value-{k}-\u00e9"  # non-ASCII catches encoding slips
    if typename in ("float32", "float64"):
        return (k + 1) * 0.25 - 3.0  # exactly representable in float32
    if typename in _INT_RANGES:
        return (k * 7919 + 3) % _INT_RANGES[typename] + (1 if typename.startswith("u") else 0)
    raise ValueError(f"unhandled base type {typename}")


def sample_values(store: Typestore, msgtype: str, k: int = 1) -> dict:
    """Field name -> value for ``msgtype``; nested messages are dicts, arrays are lists."""
    values = {}
    for i, (name, (node, spec)) in enumerate(store.fielddefs[msgtype][1]):
        values[name] = _field_value(store, node, spec, k * 31 + i)
    return values


def _field_value(store, node, spec, k):
    if node == Nodetype.BASE:
        return _base_value(spec[0], k)
    if node == Nodetype.NAME:
        return sample_values(store, spec, k)
    inner, size = spec
    length = size if node == Nodetype.ARRAY else SEQUENCE_LENGTH
    return [_field_value(store, inner[0], inner[1], k + j) for j in range(length)]


def to_rosbags(store: Typestore, msgtype: str, values: dict):
    cls = store.types[msgtype]
    kwargs = {}
    for name, (node, spec) in store.fielddefs[msgtype][1]:
        kwargs[name] = _to_rosbags_field(store, node, spec, values[name])
    return cls(**kwargs)


def _to_rosbags_field(store, node, spec, value):
    if node == Nodetype.BASE:
        return value
    if node == Nodetype.NAME:
        return to_rosbags(store, spec, value)
    inner_node, inner_spec = spec[0]
    if inner_node == Nodetype.BASE and inner_spec[0] not in ("string", "bool"):
        dtype = {"float32": np.float32, "float64": np.float64, "byte": np.uint8, "char": np.uint8}.get(
            inner_spec[0], np.dtype(inner_spec[0]))
        return np.asarray(value, dtype=dtype)
    return [_to_rosbags_field(store, inner_node, inner_spec, v) for v in value]


def from_any(msg) -> dict:
    """A rosbags dataclass or rclpy message object -> nested dict of plain values."""
    if hasattr(msg, "get_fields_and_field_types"):
        names = msg.get_fields_and_field_types().keys()
    else:
        # ROS field names are lower case; rosbags also lists constants (upper case) and __msgtype__.
        names = [f.name for f in dataclasses.fields(msg) if f.name.islower() and f.name != "__msgtype__"]
    out = {}
    for name in names:
        value = getattr(msg, name)
        if hasattr(value, "get_fields_and_field_types") or hasattr(value, "__dataclass_fields__"):
            out[name] = from_any(value)
        elif isinstance(value, list | tuple):
            out[name] = [v if isinstance(v, str | bool | int | float) else from_any(v) for v in value]
        elif hasattr(value, "tolist"):  # numpy arrays and array.array
            out[name] = value.tolist()
        else:
            out[name] = value
    return out


def fill_rclpy(msg, values: dict):
    """Set the fields of an rclpy message instance from a nested dict; returns the message."""
    for name, value in values.items():
        current = getattr(msg, name)
        if isinstance(value, dict):
            fill_rclpy(current, value)
        elif isinstance(value, list) and value and isinstance(value[0], dict):
            item_type = type(current[0]) if current else _sequence_item_class(msg, name)
            setattr(msg, name, [fill_rclpy(item_type(), v) for v in value])
        else:
            setattr(msg, name, value)
    return msg


def _sequence_item_class(msg, name):
    type_name = msg.get_fields_and_field_types()[name]
    inner = type_name.split("<", 1)[-1].rstrip(">").split("[")[0]
    package, cls = inner.split("/")
    return getattr(importlib.import_module(f"{package}.msg"), cls)


def differences(expected, actual, path: str = "") -> list[str]:
    """Field-by-field differences between two nested dicts (empty when equal)."""
    if isinstance(expected, dict):
        if not isinstance(actual, dict):
            return [f"{path}: expected a message, got {actual!r}"]
        diffs = []
        for key in expected.keys() | actual.keys():
            if key not in actual or key not in expected:
                diffs.append(f"{path}.{key}: present on one side only")
            else:
                diffs += differences(expected[key], actual[key], f"{path}.{key}")
        return diffs
    if isinstance(expected, list):
        if not isinstance(actual, list) or len(actual) != len(expected):
            return [f"{path}: expected {expected!r}, got {actual!r}"]
        return [d for i, (e, a) in enumerate(zip(expected, actual)) for d in differences(e, a, f"{path}[{i}]")]
    return [] if expected == actual else [f"{path}: expected {expected!r}, got {actual!r}"]
