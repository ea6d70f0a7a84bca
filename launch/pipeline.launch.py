"""ros2 launch m2h_ros pipeline.launch.py [episodes:=3] [controller:=doa] [world:=map:PATH/map.yaml] ...

The five nodes with their params files from the package share, as scripts/run_pipeline.py starts
them (`ros2 launch m2h_ros pipeline.launch.py --show-args` lists every argument). Each node prepares
the data it needs. The run ends when the simulator exits after its last episode; any node that exits
with an error (or killed) before that ends the launch with exit code 1 naming it. Results go to a fresh
runs/<date-time> folder unless output:= names one (overwrite:=true replaces a bag there). With
live_view:=true, live_view_node also serves the run to Foxglove (params/live_view_node.yaml:
ws://127.0.0.1:8765). Every argument is checked before any node starts (a bad value ends the launch naming the argument
and the values it accepts), and every node stops should the launch process die.
"""


from launch import LaunchDescription
from launch.actions import DeclareLaunchArgument
from launch.conditions import IfCondition
from launch.substitutions import LaunchConfiguration
from launch_ros.actions import Node

from m2h_ros.node_configs import NODE_CONFIGS
from m2h_ros.ros.launching import (Argument, check_arguments, declare, dds_profile, exit_handler, node_settings,
                                   run_directory, stop_with_launch)

NODES = NODE_CONFIGS  # node -> its config dataclass, in start order
OPTIONAL = {"live_view_node": "live_view"}  # node -> the argument that starts it
ARGUMENTS = (
    Argument("task", "sim_node", "task"),
    Argument("sound_split", "sim_node", "sound_split"),
    Argument("first_episode", "sim_node", "first_episode"),
    Argument("episodes", "sim_node", "num_episodes", default="3"),
    Argument("mode", "sim_node", "mode"),
    Argument("rate_hz", "sim_node", "rate_hz"),
    Argument("step_timeout_s", "sim_node", "step_timeout_s"),
    Argument("startup_timeout_s", "sim_node", "startup_timeout_s"),
    Argument("start_delay_s", "sim_node", "start_delay_s"),
    Argument("head", "sim_node", "head"),
    Argument("world", "sim_node", "world"),
    Argument("controller", "controller_node", "policy"),
    Argument("controller_checkpoint", "controller_node", "checkpoint"),
    Argument("separator_checkpoint", "separator_node", "checkpoint"),
    Argument("output", "recorder_node", "output", default=run_directory(),
             description="run directory: the bag in OUTPUT/bag, the scores in OUTPUT/scores (default: a fresh "
                         "runs/<date-time> per launch)"),
    Argument("overwrite", "recorder_node", "overwrite",
             description="replace a bag already in the run directory (else the recorder stops, naming it)"),
    # What the bag keeps: YAML lists of topic names or patterns ([/camera/*,/tf]), rate limits TOPIC=HZ.
    Argument("record_topics", "recorder_node", "topics"),
    Argument("record_exclude", "recorder_node", "exclude"),
    Argument("record_max_rate_hz", "recorder_node", "max_rate_hz"),
    Argument("keep_derived", "recorder_node", "keep_derived"),
    Argument("compression", "recorder_node", "compression"),
)


def generate_launch_description():
    share, params, configs, overrides = node_settings(NODES, ARGUMENTS)
    output = LaunchConfiguration("output")  # the run directory, not the bag itself
    overrides["recorder_node"]["output"] = [output, "/bag"]  # a list of text and substitutions: one string
    overrides["evaluator_node"] = {"output_dir": [output, "/scores"], "episodes": overrides["sim_node"]["num_episodes"]}
    overrides["sim_node"]["expect_nodes"] = [name for name in NODES if name != "sim_node" and name not in OPTIONAL]
    optional = [DeclareLaunchArgument("live_view", default_value="false", choices=["true", "false"],
                                      description="also serve the run to Foxglove (live_view_node)")]
    nodes = {name: Node(package="m2h_ros", executable=name, name=name, output="screen",
                        parameters=[params[name], overrides.get(name, {})],
                        condition=IfCondition(LaunchConfiguration(OPTIONAL[name])) if name in OPTIONAL else None)
             for name in NODES}
    handlers = [exit_handler(action, name, finishes_run=name == "sim_node") for name, action in nodes.items()]
    # Every argument checked before any node starts; each node stops should the launch process die.
    check = check_arguments(ARGUMENTS, configs, {"sim_node": {"expect_nodes": overrides["sim_node"]["expect_nodes"]}})
    return LaunchDescription([*declare(ARGUMENTS, configs), *optional, check, stop_with_launch(), *dds_profile(share),
                              *nodes.values(),
                              *handlers])
