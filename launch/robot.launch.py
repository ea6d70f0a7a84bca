"""ros2 launch m2h_ros robot.launch.py [target_class:=speech] [steps:=20] [controller:=move2hear] [device:=NAME] ...

Robot mode: the pipeline on a robot, without the simulator and the evaluator. capture_node records
the robot's microphones (device:=), or with microphones:=audio_common audio_common_adapter reads the
robot's audio_common stream; episode_driver turns the stream into steps (a step's
frame is captured after the base finished the step before), separator_node and controller_node work
as in simulation, base_node carries each command out on the base (odom in, cmd_vel out), and the
recorder writes the run to a fresh runs/<date-time>/bag. A driver whose topics have other names
is remapped: odom_topic:=, cmd_vel_topic:=, rgb_topic:=, depth_topic:= (the bag leaves out the raw
camera streams under the names given, unless record_exclude:= says otherwise). The shipped Move2Hear policies read the
camera: camera:=true (default) passes the robot's RGB-D images (camera/rgb/image_raw and
camera/depth/image_raw, 32FC1 metres, at the policy's 128 x 128); camera:=false runs only controllers
that read no images (the training-free baselines) and refuses the others at start. The launch ends
when the episode's last step is out (exit 0) or when any node fails (exit 1, naming it). Every
argument is checked before any node starts (a bad value ends the launch naming the argument and the
values it accepts), and every node stops should the launch process die.
"""


from launch import LaunchDescription
from launch.actions import DeclareLaunchArgument
from launch.conditions import IfCondition
from launch.substitutions import EqualsSubstitution, LaunchConfiguration
from launch_ros.actions import Node

from m2h_ros.node_configs import DRIVER_TOPICS, MICROPHONES, ROBOT_CONFIGS, ROBOT_RECORDING, ROBOT_REMAPS
from m2h_ros.ros.launching import (Argument, check_arguments, dds_profile, declare, exit_handler, node_settings,
                                   run_directory, stop_with_launch)

NODES = ROBOT_CONFIGS  # node -> its config dataclass, in start order
# Not the raw camera streams, under the driver's names: a list its declaration fills in at launch.
ROBOT_EXCLUDE = ["[", LaunchConfiguration("rgb_topic"), ",", LaunchConfiguration("depth_topic"), "]"]
ARGUMENTS = (
    Argument("target_class", "episode_driver", "target_class"),
    Argument("steps", "episode_driver", "steps"),
    Argument("task", "episode_driver", "task"),
    Argument("camera", "episode_driver", "camera"),
    Argument("input_timeout_s", "episode_driver", "input_timeout_s"),
    Argument("controller", "controller_node", "policy"),
    Argument("controller_checkpoint", "controller_node", "checkpoint"),
    Argument("separator_checkpoint", "separator_node", "checkpoint"),
    Argument("device", "capture_node", "device"),
    Argument("output", "recorder_node", "output", default=run_directory(),
             description="run directory: the bag in OUTPUT/bag (default: a fresh runs/<date-time> per launch)"),
    Argument("overwrite", "recorder_node", "overwrite",
             description="replace a bag already in the run directory (else the recorder stops, naming it)"),
    # What the bag keeps: YAML lists of topic names or patterns ([/camera/*,/tf]), rate limits TOPIC=HZ.
    Argument("record_topics", "recorder_node", "topics"),
    Argument("record_exclude", "recorder_node", "exclude", default=ROBOT_EXCLUDE,
             description="topics never to record, names or shell-style patterns (default: the raw camera "
                         "streams under the names rgb_topic:= and depth_topic:= give; each step's images are "
                         "recorded apart)"),
    Argument("record_max_rate_hz", "recorder_node", "max_rate_hz"),
    Argument("keep_derived", "recorder_node", "keep_derived"),
    Argument("compression", "recorder_node", "compression", default=ROBOT_RECORDING["compression"]),
)


def generate_launch_description():
    share, params, configs, overrides = node_settings(NODES, ARGUMENTS)
    overrides["recorder_node"]["output"] = [LaunchConfiguration("output"), "/bag"]
    # One camera and one target class for every node that needs them.
    overrides["controller_node"]["camera"] = overrides["episode_driver"]["camera"]
    overrides["separator_node"] = {**overrides.get("separator_node", {}),
                                   "target_class": overrides["episode_driver"]["target_class"]}
    microphones = [DeclareLaunchArgument("microphones", default_value="capture", choices=list(MICROPHONES),
                                         description="capture: a microphone PortAudio sees (capture_node); "
                                                     "audio_common: the robot's audio_common stream")]
    # The driver's own topic names (odom_topic:=/wheel/odometry ...), remapped in every node that uses them.
    driver = [DeclareLaunchArgument(f"{key}_topic", default_value=topic,
                                    description=f"{what} as the robot's driver names it")
              for key, (topic, _, what) in DRIVER_TOPICS.items()]
    remaps = {name: [*ROBOT_REMAPS.get(name, ()), *((topic, LaunchConfiguration(f"{key}_topic"))
                                                   for key, (topic, users, _) in DRIVER_TOPICS.items() if name in users)]
              for name in NODES}
    source = {node: IfCondition(EqualsSubstitution(LaunchConfiguration("microphones"), choice))
              for choice, node in MICROPHONES.items()}
    nodes = {name: Node(package="m2h_ros", executable=name, name=name, output="screen",
                        parameters=[params[name], overrides.get(name, {})], remappings=remaps[name],
                        condition=source.get(name))
             for name in NODES}
    handlers = [exit_handler(action, name, finishes_run=name == "episode_driver") for name, action in nodes.items()]
    # Every argument checked before any node starts; each node stops should the launch process die.
    # The driver's names first: record_exclude's default is made of them.
    return LaunchDescription([*driver, *declare(ARGUMENTS, configs), *microphones, check_arguments(ARGUMENTS, configs),
                              stop_with_launch(), *dds_profile(share), *nodes.values(),
                              *handlers])
