"""What the launch files share: launch arguments that map onto node parameters (defaults and
descriptions from the params files and the config dataclasses), a fresh run directory per launch,
the DDS profile, and the handlers that end a run when any node exits.

Jazzy's launch service returns 0 after any shutdown, whatever the nodes' exit codes; only an
exception raised inside launch makes ``ros2 launch`` exit 1. So a node that exits before the run
finished, or with an error, raises :class:`NodeExited` from its exit handler: launch logs the
message (naming the node), stops the other nodes and exits 1."""

from __future__ import annotations

import atexit
import dataclasses
import os
import signal
from dataclasses import dataclass
from datetime import datetime
from pathlib import Path
from typing import List, get_type_hints

from launch.actions import (DeclareLaunchArgument, EmitEvent, OpaqueFunction, RegisterEventHandler,
                            SetEnvironmentVariable)
from launch.event_handlers import OnProcessExit
from launch.events import Shutdown
from launch.substitutions import LaunchConfiguration
from launch_ros.parameter_descriptions import ParameterValue

from m2h_ros.config import Config, accepted_values, typed_value
from m2h_ros.errors import ConfigError
from m2h_ros.ros import stop_signals
from m2h_ros.ros.stop_signals import PARENT_ENV


class NodeExited(RuntimeError):
    """A node of a launched run exited before the run finished, or with an error."""


class LaunchArgumentError(ValueError):
    """A launch argument's value its node would refuse: raised before any node starts."""


@dataclass(frozen=True)
class Argument:
    """``ros2 launch ... NAME:=VALUE`` sets ``field`` of ``node`` (default: the node's params file)."""

    name: str
    node: str
    field: str
    default: str | list | None = None  # None: the value in the node's params file; a list: substitutions
    description: str | None = None  # None: the field's own


def run_directory() -> str:
    """A fresh folder per launch, as scripts/run_pipeline.py makes: a second launch with the defaults
    must not find the first one's bag."""
    return os.path.join("runs", datetime.now().strftime("%Y%m%d-%H%M%S"))


def declare(arguments: tuple[Argument, ...], configs: dict[str, Config]) -> list[DeclareLaunchArgument]:
    """One DeclareLaunchArgument per argument, described by the config field it sets."""
    actions = []
    for argument in arguments:
        config = configs[argument.node]
        field = next(f for f in dataclasses.fields(config) if f.name == argument.field)
        value = getattr(config, argument.field) if argument.default is None else argument.default
        if isinstance(value, bool):
            value = str(value).lower()
        elif isinstance(value, tuple):  # a YAML list, as typed after :=
            value = "[" + ",".join(map(str, value)) + "]"
        choices = field.metadata["choices"]
        actions.append(DeclareLaunchArgument(
            argument.name, default_value=value if isinstance(value, list) else str(value),
            description=argument.description or f"{argument.node}.{argument.field}: {field.metadata['description']}",
            choices=[str(c) for c in choices] if choices else None))
    return actions


def parameters(arguments: tuple[Argument, ...], configs: dict[str, Config]) -> dict[str, dict[str, ParameterValue]]:
    """node -> {field: the launch argument's value, typed as the field} (a path of digits stays a string)."""
    out: dict[str, dict[str, ParameterValue]] = {}
    for argument in arguments:
        kind = get_type_hints(type(configs[argument.node]))[argument.field]
        if getattr(kind, "__origin__", None) is tuple:  # launch types a list as typing.List
            kind = List[kind.__args__[0]]  # noqa: UP006 (launch's own spelling)
        out.setdefault(argument.node, {})[argument.field] = ParameterValue(LaunchConfiguration(argument.name),
                                                                         value_type=kind)
    return out


def node_settings(nodes: dict[str, type[Config]], arguments: tuple[Argument, ...]
                  ) -> tuple[str, dict[str, str], dict[str, Config], dict[str, dict[str, ParameterValue]]]:
    """The installed package's share folder, each node's params file there, the config that file sets,
    and the launch arguments' overrides (:func:`parameters`)."""
    from ament_index_python.packages import get_package_share_directory  # looked up when a launch file runs

    share = get_package_share_directory("m2h_ros")
    params = {name: os.path.join(share, "params", f"{name}.yaml") for name in nodes}
    configs = {name: config.from_yaml(params[name], name) for name, config in nodes.items()}
    return share, params, configs, parameters(arguments, configs)


def checked_values(values: dict[str, str], arguments: tuple[Argument, ...], configs: dict[str, Config],
                   fixed: dict[str, dict[str, object]] | None = None) -> dict[str, Config]:
    """Each node's config with the launch arguments' ``values`` (name -> text, as typed after ``:=``) and
    the ``fixed`` values the launch file sets: LaunchArgumentError naming the argument, what it sets and
    the values it accepts, for the first value its node would refuse (a wrong type, range or choice, a
    missing file)."""
    changes: dict[str, dict[str, object]] = {node: dict(values) for node, values in (fixed or {}).items()}
    for argument in arguments:
        if argument.name not in values:
            continue
        config = configs[argument.node]
        field = next(f for f in dataclasses.fields(config) if f.name == argument.field)
        text = values[argument.name]
        try:
            value = typed_value(type(config), argument.field, text)
            config.replace(**{argument.field: value})
        except ConfigError as exc:
            accepted = accepted_values(type(config), field)
            raise LaunchArgumentError(
                f"launch argument {argument.name}:={text} ({argument.node}.{argument.field}): {exc}"
                + ("" if accepted == "text" else f"; accepted: {accepted}")) from None  # text: the error says it
        changes.setdefault(argument.node, {})[argument.field] = value
    checked = dict(configs)
    for node, node_changes in changes.items():  # what only the values together decide
        try:
            checked[node] = configs[node].replace(**node_changes)
        except ConfigError as exc:
            names = [f"{a.name}:={values[a.name]}" for a in arguments if a.node == node and a.name in values]
            raise LaunchArgumentError(f"launch arguments {', '.join(names)} ({node}): {exc}") from None
    return checked


def check_arguments(arguments: tuple[Argument, ...], configs: dict[str, Config],
                    fixed: dict[str, dict[str, object]] | None = None) -> OpaqueFunction:
    """The launch action that checks every argument (:func:`checked_values`) before any node starts: placed
    before the nodes, it ends the launch (exit 1, the message naming the argument) with none started.
    launch_ros would convert each value only as it starts that value's node, so a mistyped argument of
    the last node left the others running."""

    def check(context) -> list:
        checked_values({a.name: context.launch_configurations[a.name] for a in arguments
                        if a.name in context.launch_configurations}, arguments, configs, fixed)
        return []

    return OpaqueFunction(function=check)


def stop_with_launch() -> SetEnvironmentVariable:
    """Each node stops (SIGTERM) when the launch process dies, however it dies (m2h_ros.nodes.entry reads
    the variable): none outlives its launch to join the next run's graph. And the launch process, once it
    exits, ignores Ctrl-C: Python's finalisation puts the default handler back, and a Ctrl-C still held
    then killed it (exit -2) after every node had stopped cleanly."""
    atexit.register(stop_signals.ignore)
    return SetEnvironmentVariable(PARENT_ENV, str(os.getpid()))


def dds_profile(share: str | Path) -> list[SetEnvironmentVariable]:
    """The Fast DDS profile env.sh and run_pipeline.py set (50 ms heartbeats repair lost fragments of
    the large step messages), unless the environment names one already."""
    if os.environ.get("FASTRTPS_DEFAULT_PROFILES_FILE"):
        return []
    return [SetEnvironmentVariable("FASTRTPS_DEFAULT_PROFILES_FILE", str(Path(share) / "params" / "fastdds.xml"))]


def cause(code: int) -> str:
    """Where the reason for a node's exit code is to be found."""
    if code < 0:
        try:
            name = signal.Signals(-code).name
        except ValueError:
            name = f"signal {-code}"
        return f"killed by {name} from outside the launch: the node could log nothing"
    return "its log above says why"


def exit_handler(node_action, name: str, *, finishes_run: bool) -> RegisterEventHandler:
    """When ``name`` exits: a clean exit shuts the launch down (the node that finishes the run,
    ``finishes_run``, did; any other exits 0 only when stopped from outside, as by a terminal's Ctrl-C,
    which reaches the nodes as well as launch); any other exit before shutdown, or an error exit at any
    time, raises NodeExited."""

    def on_exit(event, context):
        code = event.returncode
        if not context.is_shutdown:
            if code == 0:  # the run's end, or a node asked to stop (a Ctrl-C that reached it before launch)
                reason = f"{name} finished the run" if finishes_run else f"{name} was stopped (exit code 0)"
                return [EmitEvent(event=Shutdown(reason=reason))]
            raise NodeExited(f"{name} exited with code {code} before the run finished ({cause(code)}); "
                             "stopping the other nodes")
        if code > 0:  # stopped by launch: 0, or a signal's negative code; a positive code is an error
            raise NodeExited(f"{name} exited with code {code} while the run was stopping ({cause(code)})")
        return None

    return RegisterEventHandler(OnProcessExit(target_action=node_action, on_exit=on_exit))
