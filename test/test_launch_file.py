"""The launch file (for machines with `ros2 launch`, which this venv lacks) starts every node of the
pipeline with its own params file and overrides its config dataclass accepts, declares every setting a
user needs as an argument and uses it, gives each launch a fresh run directory, sets the DDS profile,
ends the run with the simulator and on any other node's exit (naming it), and is installed with the
package.

`launch`, `launch_ros` and the package index are stood in for at the import boundary: each class the
file imports records what it was built with, and the description generate_launch_description()
returns is inspected. Substitutions are performed and parameter values typed as launch_ros does
(a substituted string is read as YAML), so an override the node would reject fails here.
"""

import importlib.util
import os
import re
import sys
import types
from pathlib import Path

import pytest
import yaml

from m2h_ros import topics
from m2h_ros.node_configs import NODE_CONFIGS, PIPELINE_NODES, ROBOT_CONFIGS

ROOT = Path(__file__).resolve().parents[1]
LAUNCH = ROOT / "launch" / "pipeline.launch.py"
ROBOT_LAUNCH = ROOT / "launch" / "robot.launch.py"
CONFIGS = {**NODE_CONFIGS, **ROBOT_CONFIGS}
STOOD_IN = ("launch", "launch.actions", "launch.conditions", "launch.event_handlers", "launch.events",
            "launch.substitutions", "launch_ros", "launch_ros.actions", "launch_ros.substitutions",
            "launch_ros.parameter_descriptions")
# What a user of the pipeline sets per run: each must be a launch argument.
USER_SETTINGS = {"task", "sound_split", "first_episode", "episodes", "mode", "rate_hz", "step_timeout_s",
                 "startup_timeout_s", "start_delay_s", "head", "world", "controller", "separator_checkpoint", "output", "overwrite"}


class Entity:
    """Any launch class: remembers the arguments it was built with."""

    def __init__(self, *args, **kwargs):
        self.args, self.kwargs = args, kwargs

    def __repr__(self) -> str:
        return f"{type(self).__name__}(*{self.args}, **{self.kwargs})"


def stand_in(module_name: str) -> types.ModuleType:
    module, classes = types.ModuleType(module_name), {}

    def entity_class(name: str) -> type:
        if name.startswith("__"):
            raise AttributeError(name)
        return classes.setdefault(name, type(name, (Entity,), {"__module__": module_name}))

    module.__getattr__ = entity_class
    return module


def entities(value) -> list[Entity]:
    """Every Entity reachable from ``value`` through arguments, lists and dicts, each once."""
    found = {}
    stack = [value]
    while stack:
        value = stack.pop()
        if isinstance(value, Entity):
            if id(value) in found:
                continue
            found[id(value)] = value
            value = [*value.args, *value.kwargs.values()]
        if isinstance(value, dict):
            value = [*value.keys(), *value.values()]
        if isinstance(value, list | tuple):
            stack.extend(reversed(value))
    return list(found.values())


def of_kind(description: Entity, kind: str) -> list[Entity]:
    return [e for e in entities(description) if type(e).__name__ == kind]


def argument(entity: Entity, position: int, name: str):
    return entity.args[position] if len(entity.args) > position else entity.kwargs[name]


def load(monkeypatch, path: Path, *, installed: bool = False) -> types.ModuleType:
    """The launch file at ``path`` over the stand-ins; its package share is the source tree, or with
    ``installed`` the one the ament index finds (the built workspace's, as ``ros2 launch`` reads it)."""
    monkeypatch.delenv("FASTRTPS_DEFAULT_PROFILES_FILE", raising=False)
    for name in STOOD_IN:
        monkeypatch.setitem(sys.modules, name, stand_in(name))
    monkeypatch.delitem(sys.modules, "m2h_ros.ros.launching", raising=False)  # imported again over the stand-ins
    if not installed:
        index = types.ModuleType("ament_index_python.packages")
        index.get_package_share_directory = {"m2h_ros": str(ROOT)}.__getitem__  # the source tree's params/
        monkeypatch.setitem(sys.modules, "ament_index_python.packages", index)
    spec = importlib.util.spec_from_file_location(path.stem.replace(".", "_"), path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


@pytest.fixture
def launch_module(monkeypatch) -> types.ModuleType:
    return load(monkeypatch, LAUNCH)


@pytest.fixture
def description(launch_module) -> Entity:
    return launch_module.generate_launch_description()


@pytest.fixture
def defaults(description) -> dict[str, str]:
    return {argument(a, 0, "name"): a.kwargs["default_value"] for a in of_kind(description, "DeclareLaunchArgument")}


def nodes(description) -> dict[str, Entity]:
    found = {node.kwargs["name"]: node for node in of_kind(description, "Node")}
    assert len(found) == len(of_kind(description, "Node")), "two nodes share a name"
    return found


def perform(value, defaults: dict[str, str]) -> str:
    """The string a substitution (or a list of them, concatenated) gives with the arguments' defaults."""
    if isinstance(value, str):
        return value
    if isinstance(value, list | tuple):
        return "".join(perform(v, defaults) for v in value)
    if type(value).__name__ == "LaunchConfiguration":
        name = argument(value, 0, "variable_name")
        assert name in defaults, f"LaunchConfiguration({name!r}) has no DeclareLaunchArgument"
        return perform(defaults[name], defaults)
    if type(value).__name__ == "TextSubstitution":
        return value.kwargs["text"]
    if type(value).__name__ == "ParameterValue":
        return perform(value.args[0], defaults)
    raise AssertionError(f"this test cannot perform {value!r}: teach perform() what it gives")


def parameter_value(value, defaults: dict[str, str]):
    """The typed value the node receives (launch_ros: a list of plain values is an array parameter,
    anything holding a substitution is one string, and a string is read as YAML)."""
    if isinstance(value, bool | int | float):
        return value
    if isinstance(value, list | tuple) and not any(isinstance(v, Entity) for v in value):
        return tuple(value)
    text = perform(value, defaults)
    if type(value).__name__ == "ParameterValue" and value.kwargs.get("value_type") in (int, float, str):
        return value.kwargs["value_type"](text)  # typed as its field: a path of digits stays a string
    loaded = yaml.safe_load(text)
    if loaded is None:
        return ""
    if isinstance(loaded, list):  # a list argument ([a,b], launch's typing.List): the node's tuple
        return tuple(loaded)
    return loaded if type(loaded) in (bool, int, float, str) else text


def resolved_config(node: Entity, defaults: dict[str, str]):
    """The node's config as ROS would give it: its params file, then each override dict in order."""
    name = node.kwargs["name"]
    assert name in CONFIGS, f"{name}: a node this test knows no config dataclass of"
    files = [p for p in node.kwargs["parameters"] if isinstance(p, str | Path)]
    config = CONFIGS[name].from_yaml(files[0], name)
    for overrides in (p for p in node.kwargs["parameters"] if isinstance(p, dict)):
        config = config.replace(**{key: parameter_value(v, defaults) for key, v in overrides.items()})
    return config


def test_every_node_starts_with_its_own_params_file(description):
    started = nodes(description)
    assert {"sim_node", *PIPELINE_NODES} <= set(started)  # (nodes such as a microphone's are optional)
    for name, node in started.items():
        assert node.kwargs["package"] == "m2h_ros" and node.kwargs["executable"] == name
        files = [p for p in node.kwargs["parameters"] if isinstance(p, str | Path)]
        assert [os.path.normpath(p) for p in files] == [str(ROOT / "params" / f"{name}.yaml")], name
        CONFIGS[name].from_yaml(files[0], name)  # its section loads into its own dataclass


def test_every_override_is_a_typed_field_of_its_nodes_config(description, defaults):
    overridden = set()
    for name, node in nodes(description).items():
        for overrides in (p for p in node.kwargs["parameters"] if isinstance(p, dict)):
            for key, value in overrides.items():
                # replace() names an unknown field; __post_init__ a wrong type, range or choice.
                config = resolved_config(node, defaults)
                assert getattr(config, key) == parameter_value(value, defaults), (name, key)
                overridden.add(f"{name}.{key}")
    assert {"sim_node.num_episodes", "sim_node.task", "controller_node.policy"} <= overridden


def test_every_declared_argument_is_used_and_every_used_one_declared(description, defaults):
    used = {argument(c, 0, "variable_name") for c in of_kind(description, "LaunchConfiguration")}
    assert used == set(defaults)
    started = nodes(description)
    sim = resolved_config(started["sim_node"], defaults)
    assert sim.num_episodes == int(defaults["episodes"]) and sim.task == defaults["task"]
    assert resolved_config(started["controller_node"], defaults).policy == defaults["controller"]


def exit_handlers(description) -> dict:
    """node name -> the on_exit callable of its OnProcessExit handler."""
    names = {id(node): name for name, node in nodes(description).items()}
    return {names[id(h.kwargs["target_action"])]: h.kwargs["on_exit"] for h in of_kind(description, "OnProcessExit")}


def test_the_simulator_waits_for_every_node_and_its_exit_ends_the_run(description, defaults):
    started = nodes(description)
    sim = resolved_config(started["sim_node"], defaults)
    assert set(sim.expect_nodes) == set(started) & set(PIPELINE_NODES)
    running = types.SimpleNamespace(is_shutdown=False)
    (shutdown,) = exit_handlers(description)["sim_node"](types.SimpleNamespace(returncode=0), running)
    assert type(shutdown.kwargs["event"]).__name__ == "Shutdown"


def test_any_other_exit_ends_the_launch_with_an_error_naming_the_node(description):
    # Jazzy's launch returns 0 after any shutdown: only an exception out of a handler makes it exit 1.
    node_exited = sys.modules["m2h_ros.ros.launching"].NodeExited  # as imported over the stand-ins
    handlers = exit_handlers(description)
    assert set(handlers) == set(nodes(description))
    running, stopping = types.SimpleNamespace(is_shutdown=False), types.SimpleNamespace(is_shutdown=True)
    for name, on_exit in handlers.items():
        for code in (2, -9):
            with pytest.raises(node_exited, match=f"^{name} exited with code {code} before the run finished"):
                on_exit(types.SimpleNamespace(returncode=code), running)
        # A node exits 0 only when asked to stop: a terminal's Ctrl-C reaches the nodes as well as launch, and
        # one may exit before launch has begun its own shutdown. That is a user's stop, not a failure.
        (shutdown,) = on_exit(types.SimpleNamespace(returncode=0), running)
        assert type(shutdown.kwargs["event"]).__name__ == "Shutdown"
        for code in (0, -2, -15):  # stopped by launch itself
            assert on_exit(types.SimpleNamespace(returncode=code), stopping) is None
        with pytest.raises(node_exited, match=f"^{name} exited with code 2 while the run was stopping"):
            on_exit(types.SimpleNamespace(returncode=2), stopping)
    # A killed node logged nothing: the message says what killed it instead of pointing at its log.
    with pytest.raises(node_exited, match=r"killed by SIGKILL from outside the launch: the node could log nothing"):
        handlers["separator_node"](types.SimpleNamespace(returncode=-9), running)


def test_every_setting_a_user_needs_is_an_argument(description, defaults):
    declared = {argument(a, 0, "name"): a.kwargs for a in of_kind(description, "DeclareLaunchArgument")}
    assert USER_SETTINGS <= set(declared)
    assert all(kwargs["description"] for kwargs in declared.values())
    assert declared["mode"]["choices"] == ["lockstep", "free_running"]
    started = nodes(description)
    sim = resolved_config(started["sim_node"], defaults)
    assert (sim.sound_split, sim.first_episode, sim.mode) == (defaults["sound_split"], 0, "lockstep")
    assert resolved_config(started["recorder_node"], defaults).overwrite is False


def test_each_launch_gets_a_fresh_run_directory(description, defaults):
    assert re.fullmatch(r"runs/\d{8}-\d{6}", defaults["output"])
    started = nodes(description)
    assert resolved_config(started["recorder_node"], defaults).output == defaults["output"] + "/bag"
    assert resolved_config(started["evaluator_node"], defaults).output_dir == defaults["output"] + "/scores"


def test_the_dds_profile_is_set_unless_the_environment_names_one(launch_module, monkeypatch):
    def profiles() -> list[Entity]:
        return [s for s in of_kind(launch_module.generate_launch_description(), "SetEnvironmentVariable")
                if s.args[0] == "FASTRTPS_DEFAULT_PROFILES_FILE"]

    (setting,) = profiles()
    assert setting.args == ("FASTRTPS_DEFAULT_PROFILES_FILE", str(ROOT / "params" / "fastdds.xml"))
    monkeypatch.setenv("FASTRTPS_DEFAULT_PROFILES_FILE", "/elsewhere.xml")
    assert not profiles()


def test_launch_and_launch_ros_are_declared_and_the_recipes_installed():
    package = (ROOT / "package.xml").read_text()
    for dependency in ("launch", "launch_ros"):
        assert f"<exec_depend>{dependency}</exec_depend>" in package
    assert 'glob("params/recipes/*")' in (ROOT / "setup.py").read_text()


def test_the_installed_launch_files_start_the_installed_params(monkeypatch):
    """What `ros2 launch m2h_ros FILE` runs: each launch file and params file (the Foxglove layout too) of
    the source tree is in the package share the ament index finds (setup.sh's colcon build), the same
    bytes, and each installed launch file starts its nodes with the installed params files."""
    from ament_index_python.packages import get_package_share_directory

    share = Path(get_package_share_directory("m2h_ros"))
    for pattern in ("launch/*.launch.py", "params/*.yaml", "params/*.xml", "params/*.json", "params/recipes/*"):
        sources = sorted(ROOT.glob(pattern))
        assert sources, pattern
        for source in sources:
            installed = share / source.relative_to(ROOT)
            assert installed.is_file(), f"{installed} is not installed: rebuild the workspace (scripts/setup.sh)"
            assert installed.read_bytes() == source.read_bytes(), f"{installed} differs from {source}"
    for name, expected in (("pipeline.launch.py", NODE_CONFIGS), ("robot.launch.py", ROBOT_CONFIGS)):
        description = load(monkeypatch, share / "launch" / name, installed=True).generate_launch_description()
        started = nodes(description)
        assert list(started) == list(expected), name
        for node_name, node in started.items():
            files = [Path(p) for p in node.kwargs["parameters"] if isinstance(p, str | Path)]
            assert files == [share / "params" / f"{node_name}.yaml"], (name, node_name)


def test_the_live_view_is_opt_in(description, defaults):
    view = nodes(description)["live_view_node"]
    condition = view.kwargs["condition"]
    assert type(condition).__name__ == "IfCondition"
    assert yaml.safe_load(perform(argument(condition, 0, "predicate_expression"), defaults)) is False
    for name, node in nodes(description).items():
        assert name == "live_view_node" or node.kwargs.get("condition") is None, name


@pytest.fixture
def robot(monkeypatch) -> Entity:
    return load(monkeypatch, ROBOT_LAUNCH).generate_launch_description()


def test_robot_mode_starts_the_robot_nodes_and_no_simulator(robot):
    started = nodes(robot)
    assert list(started) == list(ROBOT_CONFIGS)
    assert "sim_node" not in started and "evaluator_node" not in started
    for name, node in started.items():
        files = [p for p in node.kwargs["parameters"] if isinstance(p, str | Path)]
        assert [os.path.normpath(p) for p in files] == [str(ROOT / "params" / f"{name}.yaml")], name
    defaults = {argument(a, 0, "name"): a.kwargs["default_value"] for a in of_kind(robot, "DeclareLaunchArgument")}
    remaps = {name: {topic: perform(to, defaults) for topic, to in node.kwargs["remappings"]}
              for name, node in started.items()}
    assert remaps["capture_node"] == {topics.AUDIO: topics.MIC_AUDIO}  # frames to the episode driver
    assert remaps["audio_common_adapter"] == {topics.AUDIO: topics.MIC_AUDIO}
    for name, choice in (("capture_node", "capture"), ("audio_common_adapter", "audio_common")):
        (equals,) = started[name].kwargs["condition"].args
        assert equals.args[0].args == ("microphones",) and equals.args[1] == choice
    assert defaults["microphones"] == "capture"  # one of the two runs, the microphone by default
    assert remaps["controller_node"][topics.ODOM] == topics.STEP_ODOM
    # The robot's own odom and cmd_vel, under the pipeline's names unless the driver's are given
    assert remaps["base_node"] == {topics.ODOM: topics.ODOM, topics.CMD_VEL: topics.CMD_VEL}


def test_robot_mode_remaps_the_drivers_own_topic_names(robot):
    defaults = {argument(a, 0, "name"): a.kwargs["default_value"] for a in of_kind(robot, "DeclareLaunchArgument")}
    defaults.update(odom_topic="/wheel/odometry", cmd_vel_topic="/base/cmd_vel", rgb_topic="/head/color",
                    depth_topic="/head/depth")
    remaps = {name: {topic: perform(to, defaults) for topic, to in node.kwargs["remappings"]}
              for name, node in nodes(robot).items()}
    assert remaps["base_node"] == {topics.ODOM: "/wheel/odometry", topics.CMD_VEL: "/base/cmd_vel"}
    assert remaps["episode_driver"] == {topics.ODOM: "/wheel/odometry", topics.RGB: "/head/color",
                                        topics.DEPTH: "/head/depth"}
    # The controller reads what the episode driver stamps with each step, whatever the driver's names.
    assert remaps["controller_node"] == {topics.ODOM: topics.STEP_ODOM, topics.RGB: topics.STEP_RGB,
                                         topics.DEPTH: topics.STEP_DEPTH}
    assert remaps["capture_node"] == remaps["audio_common_adapter"] == {topics.AUDIO: topics.MIC_AUDIO}


def test_robot_mode_arguments_reach_every_node_that_needs_them(robot):
    defaults = {argument(a, 0, "name"): a.kwargs["default_value"] for a in of_kind(robot, "DeclareLaunchArgument")}
    assert {"target_class", "steps", "controller", "camera", "device", "output", "overwrite"} <= set(defaults)
    started = nodes(robot)
    driver = resolved_config(started["episode_driver"], defaults)
    assert (driver.target_class, driver.steps, driver.camera) == ("speech", 20, True)
    assert resolved_config(started["separator_node"], defaults).target_class == driver.target_class
    controller = resolved_config(started["controller_node"], defaults)
    assert controller.policy == "move2hear" and controller.camera is True  # the shipped policy, with RGB-D
    defaults["camera"], defaults["target_class"] = "false", "music"
    assert resolved_config(started["controller_node"], defaults).camera is False
    assert resolved_config(started["separator_node"], defaults).target_class == "music"


def test_robot_mode_ends_with_the_episode_driver_and_on_any_other_exit(robot):
    node_exited = sys.modules["m2h_ros.ros.launching"].NodeExited
    handlers = exit_handlers(robot)
    assert set(handlers) == set(ROBOT_CONFIGS)
    running = types.SimpleNamespace(is_shutdown=False)
    (shutdown,) = handlers["episode_driver"](types.SimpleNamespace(returncode=0), running)
    assert type(shutdown.kwargs["event"]).__name__ == "Shutdown"
    with pytest.raises(node_exited, match="^capture_node exited with code 2"):
        handlers["capture_node"](types.SimpleNamespace(returncode=2), running)


def argument_check(description):
    """The check the launch runs before its nodes, and the launch actions that come after it."""
    actions = list(description.args[0])
    (check,) = [a for a in actions if type(a).__name__ == "OpaqueFunction"]
    return check.kwargs["function"], actions[actions.index(check) + 1:]


def check_with(description, defaults: dict[str, str], **values: str) -> None:
    check, _ = argument_check(description)
    given = {**defaults, **values}
    # As launch holds them: each declared default performed (a substitution list becomes its string).
    configurations = {name: perform(value, given) for name, value in given.items()}
    assert check(types.SimpleNamespace(launch_configurations=configurations)) == []


def test_every_argument_is_checked_before_any_node_starts(description, defaults):
    _, after = argument_check(description)
    assert set(nodes(description).values()) <= set(after)  # every node comes after the check
    check_with(description, defaults)  # the defaults pass
    error = sys.modules["m2h_ros.ros.launching"].LaunchArgumentError
    with pytest.raises(error, match=r"^launch argument episodes:=abc \(sim_node.num_episodes\): .*expected an "
                                    r"integer; accepted: an integer from 1 to 100000$"):
        check_with(description, defaults, episodes="abc")
    with pytest.raises(error, match=r"episodes:=0 .*must be >= 1"):
        check_with(description, defaults, episodes="0")
    with pytest.raises(error, match=r"overwrite:=yes please .*accepted: true or false"):
        check_with(description, defaults, overwrite="yes please")
    with pytest.raises(error, match=r"controller:=no_such .*accepted: .*move2hear"):
        check_with(description, defaults, controller="no_such")
    with pytest.raises(error, match=r"head:=sofa:/nonexistent.sofa .*no such file"):
        check_with(description, defaults, head="sofa:/nonexistent.sofa")
    with pytest.raises(error, match=r"separator_checkpoint:=/nonexistent.pt .*no such file"):
        check_with(description, defaults, separator_checkpoint="/nonexistent.pt")


def test_robot_arguments_are_checked_before_any_node_starts(robot):
    defaults = {argument(a, 0, "name"): a.kwargs["default_value"] for a in of_kind(robot, "DeclareLaunchArgument")}
    _, after = argument_check(robot)
    assert set(nodes(robot).values()) <= set(after)
    check_with(robot, defaults)
    with pytest.raises(sys.modules["m2h_ros.ros.launching"].LaunchArgumentError,
                       match=r"^launch argument steps:=abc \(episode_driver.steps\)"):
        check_with(robot, defaults, steps="abc")


def test_each_node_stops_should_the_launch_process_die(description, robot):
    for launched in (description, robot):
        (setting,) = [s for s in of_kind(launched, "SetEnvironmentVariable") if s.args[0] == "M2H_STOP_WITH_PARENT"]
        assert setting.args[1] == str(os.getpid())  # the process that runs the launch file
        actions = list(launched.args[0])
        assert actions.index(setting) < min(actions.index(n) for n in nodes(launched).values())


def test_what_the_bag_keeps_is_set_by_arguments_and_robot_mode_leaves_out_the_raw_camera(description, defaults,
                                                                                        robot):
    recorder = resolved_config(nodes(description)["recorder_node"], defaults)
    assert (recorder.topics, recorder.exclude, recorder.max_rate_hz, recorder.compression) == ((), (), (), "none")
    defaults = {**defaults, "record_topics": "[/audio,/cmd]", "record_exclude": "[/camera/*]",
                "record_max_rate_hz": "[/odom=2]", "compression": "zstd"}
    recorder = resolved_config(nodes(description)["recorder_node"], defaults)
    assert (recorder.topics, recorder.exclude, recorder.max_rate_hz, recorder.compression) == (
        ("/audio", "/cmd"), ("/camera/*",), ("/odom=2",), "zstd")
    check_with(description, defaults)
    error = ValueError  # LaunchArgumentError of the launching module loaded for the pipeline (robot loads another)
    with pytest.raises(error, match=r"record_exclude:=/camera/\* .*accepted: a list \[A,B,...\] of str"):
        check_with(description, defaults, record_exclude="/camera/*")  # launch_ros would refuse it at the node
    with pytest.raises(error, match=r"record_max_rate_hz:=\[/odom=fast\] .*not TOPIC=HZ"):
        check_with(description, defaults, record_max_rate_hz="[/odom=fast]")
    robot_defaults = {argument(a, 0, "name"): a.kwargs["default_value"]
                      for a in of_kind(robot, "DeclareLaunchArgument")}
    recorder = resolved_config(nodes(robot)["recorder_node"], robot_defaults)
    assert recorder.exclude == (topics.RGB, topics.DEPTH) and recorder.compression == "zstd"  # matched as /camera/...
    # A driver with its own camera names: its raw streams stay out of the bag under those names.
    robot_defaults.update(rgb_topic="/head/color", depth_topic="/head/depth")
    assert resolved_config(nodes(robot)["recorder_node"], robot_defaults).exclude == ("/head/color", "/head/depth")
    declared = [argument(a, 0, "name") for a in of_kind(robot, "DeclareLaunchArgument")]
    assert declared.index("rgb_topic") < declared.index("record_exclude")  # declared before its default uses it
