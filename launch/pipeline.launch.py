"""ros2 launch m2h_ros pipeline.launch.py [episodes:=3] [controller:=doa] [task:=near_target] [live_view:=true]

The five nodes with their params files from the package share, as scripts/run_pipeline.py starts
them (for machines with ROS 2 Jazzy and `ros2 launch`; run_pipeline.py also builds the data first
and prints the scores table, so prefer it where launch is not available). The run ends when the
simulator exits after its last episode: the other nodes are then shut down. With live_view:=true,
live_view_node also serves the run to Foxglove (params/live_view_node.yaml: ws://127.0.0.1:8765).
"""

import os

from ament_index_python.packages import get_package_share_directory
from launch import LaunchDescription
from launch.actions import DeclareLaunchArgument, EmitEvent, RegisterEventHandler
from launch.conditions import IfCondition
from launch.event_handlers import OnProcessExit
from launch.events import Shutdown
from launch.substitutions import LaunchConfiguration
from launch_ros.actions import Node

NODES = ("live_view_node", "recorder_node", "evaluator_node", "controller_node", "separator_node", "sim_node")


def generate_launch_description():
    share = get_package_share_directory("m2h_ros")
    params = {name: os.path.join(share, "params", f"{name}.yaml") for name in NODES}
    arguments = [
        DeclareLaunchArgument("episodes", default_value="3", description="episodes to play"),
        DeclareLaunchArgument("task", default_value="near_target", description="near_target | far_target"),
        DeclareLaunchArgument("controller", default_value="move2hear", description="controller_node policy"),
        DeclareLaunchArgument("output", default_value="runs/launch", description="run directory"),
        DeclareLaunchArgument("live_view", default_value="false", description="also serve the run to Foxglove"),
    ]
    output = LaunchConfiguration("output")
    overrides = {
        "sim_node": {"num_episodes": LaunchConfiguration("episodes"), "task": LaunchConfiguration("task"),
                     "expect_nodes": ["separator_node", "controller_node", "evaluator_node", "recorder_node"]},
        "controller_node": {"policy": LaunchConfiguration("controller")},
        "evaluator_node": {"output_dir": [output, "/scores"]},
        "recorder_node": {"output": [output, "/bag"]},
    }
    conditions = {"live_view_node": IfCondition(LaunchConfiguration("live_view"))}  # opt-in
    nodes = {name: Node(package="m2h_ros", executable=name, name=name, output="screen",
                        parameters=[params[name], overrides.get(name, {})], condition=conditions.get(name))
             for name in NODES}
    end_with_sim = RegisterEventHandler(OnProcessExit(target_action=nodes["sim_node"],
                                                      on_exit=[EmitEvent(event=Shutdown(reason="run finished"))]))
    return LaunchDescription([*arguments, *nodes.values(), end_with_sim])
