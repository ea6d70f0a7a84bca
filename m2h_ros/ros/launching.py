"""What the launch files share: launch arguments that map onto node parameters (defaults and
descriptions from the params files and the config dataclasses), a fresh run directory per launch,
the DDS profile, and the handlers that end a run when any node exits.

Jazzy's launch service returns 0 after any shutdown, whatever the nodes' exit codes; only an
exception raised inside launch makes ``ros2 launch`` exit 1. So a node that exits before the run
finished, or with an error, raises :class:`NodeExited` from its exit handler: launch logs the
message (naming the node), stops the other nodes and exits 1."""

from __future__ import annotations

import dataclasses
import os
from dataclasses import dataclass
from datetime import datetime
from pathlib import Path

from launch.actions import DeclareLaunchArgument, EmitEvent, RegisterEventHandler, SetEnvironmentVariable
from launch.event_handlers import OnProcessExit
from launch.events import Shutdown
from launch.substitutions import LaunchConfiguration
from launch_ros.parameter_descriptions import ParameterValue

from m2h_ros.config import Config


class NodeExited(RuntimeError):
    """A node of a launched run exited before the run finished, or with an error."""


@dataclass(frozen=True)
class Argument:
    """``ros2 launch ... NAME:=VALUE`` sets ``field`` of ``node`` (default: the node's params file)."""

    name: str
    node: str
    field: str
    default: str | None = None  # None: the value in the node's params file
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
        choices = field.metadata["choices"]
        actions.append(DeclareLaunchArgument(
            argument.name, default_value=str(value),
            description=argument.description or f"{argument.node}.{argument.field}: {field.metadata['description']}",
            choices=[str(c) for c in choices] if choices else None))
    return actions


def parameters(arguments: tuple[Argument, ...], configs: dict[str, Config]) -> dict[str, dict[str, ParameterValue]]:
    """node -> {field: the launch argument's value, typed as the field} (a path of digits stays a string)."""
    out: dict[str, dict[str, ParameterValue]] = {}
    for argument in arguments:
        kind = type(getattr(configs[argument.node], argument.field))
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


def dds_profile(share: str | Path) -> list[SetEnvironmentVariable]:
    """The Fast DDS profile env.sh and run_pipeline.py set (50 ms heartbeats repair lost fragments of
    the large step messages), unless the environment names one already."""
    if os.environ.get("FASTRTPS_DEFAULT_PROFILES_FILE"):
        return []
    return [SetEnvironmentVariable("FASTRTPS_DEFAULT_PROFILES_FILE", str(Path(share) / "params" / "fastdds.xml"))]


def exit_handler(node_action, name: str, *, finishes_run: bool) -> RegisterEventHandler:
    """When ``name`` exits: a clean exit of the node that finishes the run (``finishes_run``) shuts the
    launch down; any other exit before shutdown, or an error exit at any time, raises NodeExited."""

    def on_exit(event, context):
        code = event.returncode
        if not context.is_shutdown:
            if finishes_run and code == 0:
                return [EmitEvent(event=Shutdown(reason=f"{name} finished the run"))]
            raise NodeExited(f"{name} exited with code {code} before the run finished (its log above says "
                             "why); stopping the other nodes")
        if code > 0:  # stopped by launch: 0, or a signal's negative code; a positive code is an error
            raise NodeExited(f"{name} exited with code {code} while the run was stopping (its log above says why)")
        return None

    return RegisterEventHandler(OnProcessExit(target_action=node_action, on_exit=on_exit))
