"""Node configs as ROS parameters: every dataclass field declared with its description and range."""

import dataclasses
from typing import get_type_hints

from rcl_interfaces.msg import FloatingPointRange, IntegerRange, ParameterDescriptor, ParameterType
from rclpy.exceptions import InvalidParameterTypeException, InvalidParameterValueException
from rclpy.node import Node
from rclpy.parameter import Parameter

from m2h_ros.config import Config, unknown_names
from m2h_ros.errors import ConfigError

_PARAM_TYPES = {bool: ParameterType.PARAMETER_BOOL, int: ParameterType.PARAMETER_INTEGER,
                float: ParameterType.PARAMETER_DOUBLE, str: ParameterType.PARAMETER_STRING,
                tuple[str, ...]: ParameterType.PARAMETER_STRING_ARRAY,
                tuple[int, ...]: ParameterType.PARAMETER_INTEGER_ARRAY,
                tuple[float, ...]: ParameterType.PARAMETER_DOUBLE_ARRAY}
_INT64_MAX = 2**63 - 1
QOS_OVERRIDES = "qos_overrides."  # rclpy's own per-topic QoS parameters, declared with their endpoints


def _descriptor(f: dataclasses.Field, kind: type) -> ParameterDescriptor:
    meta = f.metadata
    text = meta["description"]
    if meta["choices"]:
        text += f" (one of: {', '.join(map(str, meta['choices']))})"
    desc = ParameterDescriptor(name=f.name, type=_PARAM_TYPES[kind], description=text, read_only=True)
    lo, hi = meta["min"], meta["max"]
    if kind is float and (lo is not None or hi is not None):
        desc.floating_point_range = [FloatingPointRange(
            from_value=float(lo if lo is not None else -1e308),
            to_value=float(hi if hi is not None else 1e308), step=0.0)]
    elif kind is int and (lo is not None or hi is not None):
        desc.integer_range = [IntegerRange(from_value=int(lo if lo is not None else -_INT64_MAX),
                                           to_value=int(hi if hi is not None else _INT64_MAX), step=0)]
    return desc


def declare_config(node: Node, config_type: type[Config]) -> Config:
    """Declare one read-only parameter per field (defaults from the dataclass) and build the config.

    Values come from --params-file / -p overrides; the dataclass validates them (ConfigError)."""
    hints = get_type_hints(config_type)
    values = {}
    for f in dataclasses.fields(config_type):
        kind = hints[f.name]
        # An empty list has no ROS type of its own: declare the type and read back None when unset.
        default = (list(f.default) if f.default else Parameter.Type.STRING_ARRAY) \
            if isinstance(f.default, tuple) else f.default
        try:
            value = node.declare_parameter(f.name, default, _descriptor(f, kind)).value
        except (InvalidParameterValueException, InvalidParameterTypeException) as exc:
            raise ConfigError(f"{config_type.__name__}.{f.name}: {exc}") from exc
        values[f.name] = f.default if value is None else value
    # rclpy drops a value given for a parameter nobody declares: a mistyped name would run on the default
    # without a word. (Node keeps the values given to it, -p and params files, only in a private member.)
    unknown = sorted(name for name in node._parameter_overrides
                     if not node.has_parameter(name) and not name.startswith(QOS_OVERRIDES))
    if unknown:
        known = sorted(node._parameters)
        raise ConfigError(f"unknown parameter(s) of {node.get_name()}: {unknown_names(unknown, known)}; known: "
                          f"{', '.join(known)}")
    return config_type.from_dict(values, source=f"parameters of {node.get_name()}")
