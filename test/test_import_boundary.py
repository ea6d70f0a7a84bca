"""Only m2h_ros.ros and m2h_ros.nodes may touch ROS: everything else imports with rclpy and every
message package blocked. The core (m2h_ros.core) must not even load torch."""

import subprocess
import sys
import textwrap

BLOCKER = textwrap.dedent("""
    import importlib.abc, pkgutil, sys
    BLOCKED = {BLOCKED}
    class Blocker(importlib.abc.MetaPathFinder):
        def find_spec(self, name, path=None, target=None):
            if name.split(".")[0] in BLOCKED:
                raise ImportError(f"blocked import of {{name}}")
    sys.meta_path.insert(0, Blocker())
    import m2h_ros
    skip = {SKIP}
    names = []
    for info in pkgutil.walk_packages(m2h_ros.__path__, "m2h_ros."):
        if not any(info.name == s or info.name.startswith(s + ".") for s in skip):
            __import__(info.name)
            names.append(info.name)
    print(len(names))
""")
ROS_MODULES = {"rclpy", "rcl_interfaces", "rosidl_runtime_py", "rosidl_parser", "builtin_interfaces",
               "std_msgs", "sensor_msgs", "geometry_msgs", "nav_msgs", "m2h_msgs", "rosgraph_msgs",
               "ament_index_python"}


def import_everything(blocked: set[str], skip: set[str]) -> int:
    code = BLOCKER.format(BLOCKED=sorted(blocked), SKIP=sorted(skip))
    result = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300)
    assert result.returncode == 0, result.stderr
    return int(result.stdout.split()[-1])


def test_everything_outside_ros_and_nodes_imports_without_ros():
    count = import_everything(ROS_MODULES, {"m2h_ros.ros", "m2h_ros.nodes"})
    assert count >= 5  # the walk really imported modules


def test_core_imports_without_torch():
    assert import_everything(ROS_MODULES | {"torch"}, {"m2h_ros.ros", "m2h_ros.nodes", "m2h_ros.models",
                                                      "m2h_ros.agents", "m2h_ros.training",
                                                      "m2h_ros.separate_cli"}) >= 3


def test_blocker_really_blocks():
    code = BLOCKER.format(BLOCKED=["rclpy"], SKIP=[]) + "\nimport rclpy\n"
    result = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300)
    assert result.returncode != 0 and "blocked import of rclpy" in result.stderr
