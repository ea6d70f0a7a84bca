"""recorder_node records what crosses the graph; SIGINT leaves a readable bag with every message intact."""

import sys
import time
from pathlib import Path

import pytest
from msg_values import differences, from_any, sample_values
from test_executables import ROS2RUN, wait_for_line

from m2h_ros.io.bag import read_messages
from m2h_ros.io.msg_defs import msg_files, typestore

pytestmark = pytest.mark.graph
PROBE = Path(__file__).with_name("msg_probe.py")


def test_recorder_sigint_leaves_a_readable_bag(processes, tmp_path):
    bag = tmp_path / "bag"
    recorder = processes.start([ROS2RUN, "m2h_ros", "recorder_node", "--ros-args",
                                "-p", f"output:={bag}", "-p", "discovery_period_s:=0.2"])
    wait_for_line(recorder, "recording to")
    publisher = processes.start([sys.executable, str(PROBE), "publish"])
    wait_for_line(recorder, "recording /probe/StepScore")  # the last type the probe advertises
    time.sleep(2.0)  # 10 Hz per topic: a couple of seconds of traffic
    code, _, err = processes.interrupt(recorder)
    processes.interrupt(publisher)
    assert code == 0, err
    assert (bag / "metadata.yaml").is_file()
    store = typestore()
    expected = {name: sample_values(store, name, k) for k, name in enumerate(sorted(msg_files()))}
    counts: dict[str, int] = {}
    for item in read_messages(bag):
        if item.topic.startswith("/probe/"):
            counts[item.msgtype] = counts.get(item.msgtype, 0) + 1
            assert differences(expected[item.msgtype], from_any(item.message)) == [], item.msgtype
    assert set(counts) == set(expected)
    assert min(counts.values()) >= 5
