"""Shared pieces of the pipeline graph tests: a tiny but complete setup (small scenes, fast
acoustics, the small real sound library, 32 px camera) and bag reading."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

from rosbags.highlevel import AnyReader

from m2h_ros.io.msg_defs import typestore

ROOT = Path(__file__).resolve().parents[2]
ROS2RUN = str(ROOT / "scripts" / "bin" / "ros2run")
# Sim parameters of the tiny setup (as NODE.PARAM=VALUE for run_pipeline's --set).
TINY_SIM = {"sound_library": "small", "scene_preset": "small", "min_source_distance": 3.0,
            "acoustics": "fast", "camera_size": 32}


def tiny_sets(**extra) -> list[str]:
    args = []
    for name, value in {**TINY_SIM, **extra}.items():
        args += ["--set", f"sim_node.{name}={value}"]
    return args


def node_env(data_dir: Path) -> dict[str, str]:
    """The node processes' environment: the tests' data dir, the sound sources setup fetched."""
    from m2h_ros.core.sounds.sources import sources_dir

    return {**os.environ, "M2H_SOUND_SOURCES": str(sources_dir()), "M2H_DATA_DIR": str(data_dir),
            "OMP_WAIT_POLICY": "PASSIVE"}


def run_pipeline(out: Path, data_dir: Path, *args: str, timeout: float = 240) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, str(ROOT / "scripts" / "run_pipeline.py"), "--out", str(out), *args],
                          capture_output=True, text=True, timeout=timeout, env=node_env(data_dir), cwd=ROOT)


def node_args(node: str, **params) -> list[str]:
    args = [ROS2RUN, "m2h_ros", node, "--ros-args", "--params-file", str(ROOT / "params" / f"{node}.yaml")]
    for name, value in params.items():
        if isinstance(value, (list, tuple)):
            value = "[" + ",".join(map(str, value)) + "]"
        elif isinstance(value, bool):
            value = str(value).lower()
        args += ["-p", f"{name}:={value}"]
    return args


def bag_messages(bag: Path) -> dict[str, list]:
    """topic -> deserialised messages in log order."""
    out: dict[str, list] = {}
    with AnyReader([bag], default_typestore=typestore()) as reader:
        for connection, _, raw in reader.messages():
            out.setdefault(connection.topic, []).append(reader.deserialize(raw, connection.msgtype))
    return out
