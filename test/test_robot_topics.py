"""Robot mode takes a driver's own topic names: run_pipeline.py --robot remaps odometry, cmd_vel and the
camera in every node that uses them (the launch file's odom_topic:= etc.: test_launch_file.py), leaves
the driver's raw camera streams out of the bag under their own names, and refuses a name ROS would not
take before any node starts."""

import subprocess
import sys

import pytest

from m2h_ros import topics
from m2h_ros.errors import ConfigError
from m2h_ros.node_configs import ROBOT_REMAPS, robot_recording, robot_remaps
from m2h_ros.paths import REPO_DIR
from scripts_as_modules import load_script


@pytest.fixture(scope="module")
def run_pipeline():
    return load_script("run_pipeline")


def test_the_pipelines_own_names_remap_nothing_but_robot_modes_own_topics():
    assert robot_remaps() == {node: tuple(pairs) for node, pairs in ROBOT_REMAPS.items()}
    assert robot_remaps({"odom": topics.ODOM, "cmd_vel": topics.CMD_VEL}) == robot_remaps()


def test_each_driver_topic_is_remapped_in_every_node_that_uses_it():
    remaps = {node: dict(pairs) for node, pairs in robot_remaps(
        {"odom": "/wheel/odometry", "cmd_vel": "base/cmd_vel", "rgb": "/head/color", "depth": "/head/depth"}).items()}
    assert remaps["base_node"] == {topics.ODOM: "/wheel/odometry", topics.CMD_VEL: "base/cmd_vel"}
    assert remaps["episode_driver"] == {topics.ODOM: "/wheel/odometry", topics.RGB: "/head/color",
                                        topics.DEPTH: "/head/depth"}
    assert remaps["controller_node"] == {topics.ODOM: topics.STEP_ODOM, topics.RGB: topics.STEP_RGB,
                                         topics.DEPTH: topics.STEP_DEPTH}
    assert robot_recording({"rgb": "/head/color", "depth": "head/depth"})["exclude"] == ("/head/color", "/head/depth")
    assert robot_recording()["exclude"] == ("/" + topics.RGB, "/" + topics.DEPTH)


@pytest.mark.parametrize("name", ["", "odom topic", "2d/odom", "/odom/", "odom:=x"])
def test_a_topic_name_ros_would_refuse_is_named(name):
    with pytest.raises(ConfigError, match="odom topic .* is not a ROS topic name"):
        robot_remaps({"odom": name})
    with pytest.raises(ConfigError, match="no driver topic 'imu'"):
        robot_remaps({"imu": "/imu"})


def test_run_pipeline_passes_the_drivers_names_to_the_nodes_and_the_recorder(run_pipeline):
    args = run_pipeline.parse_args(["--robot", "--odom-topic", "/wheel/odometry", "--cmd-vel-topic", "/base/cmd_vel",
                                    "--rgb-topic", "/head/color", "--depth-topic", "/head/depth", "--out", "runs/x"])
    assert run_pipeline.driver_topics(args) == {"odom": "/wheel/odometry", "cmd_vel": "/base/cmd_vel",
                                                "rgb": "/head/color", "depth": "/head/depth"}
    assert run_pipeline.overrides(args)["recorder_node"]["exclude"] == ("/head/color", "/head/depth")


def test_run_pipeline_refuses_a_bad_topic_name_before_any_node_starts(tmp_path):
    result = subprocess.run([sys.executable, str(REPO_DIR / "scripts" / "run_pipeline.py"), "--robot", "--out",
                             str(tmp_path / "run"), "--cmd-vel-topic", "base cmd"],
                            capture_output=True, text=True, timeout=120, cwd=REPO_DIR)
    assert result.returncode == 1 and "cmd_vel topic 'base cmd' is not a ROS topic name" in result.stderr
    assert not (tmp_path / "run" / "logs").exists()  # nothing started


def test_robot_mode_finds_the_drivers_where_ros_would_and_a_simulated_run_keeps_to_itself(run_pipeline):
    robot = run_pipeline.node_environment({"PATH": "/bin"}, robot=True)
    assert "ROS_DOMAIN_ID" not in robot and "ROS_AUTOMATIC_DISCOVERY_RANGE" not in robot  # ROS's defaults
    assert run_pipeline.node_environment({"ROS_DOMAIN_ID": "7"}, robot=True)["ROS_DOMAIN_ID"] == "7"
    simulated = run_pipeline.node_environment({"PATH": "/bin"}, robot=False)
    assert simulated["ROS_AUTOMATIC_DISCOVERY_RANGE"] == "LOCALHOST" and 1 <= int(simulated["ROS_DOMAIN_ID"]) <= 100
    assert run_pipeline.node_environment({"ROS_DOMAIN_ID": "7"}, robot=False)["ROS_DOMAIN_ID"] == "7"
