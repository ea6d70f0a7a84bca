"""recorder_node records what crosses the graph; SIGINT leaves a readable bag with every message intact;
SIGKILL loses at most about one flush period of messages."""

import os
import signal
import sys
import time
from pathlib import Path

import yaml

import pytest
from msg_values import differences, from_any, sample_values
from test_executables import ROS2RUN, wait_for_line

from m2h_ros.io.bag import read_messages
from m2h_ros.io.mcap_stream import BagStream
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


def test_recorder_sigkill_loses_at_most_about_a_flush_period(processes, tmp_path):
    bag = tmp_path / "bag"
    recorder = processes.start([ROS2RUN, "m2h_ros", "recorder_node", "--ros-args", "-p", f"output:={bag}",
                                "-p", "discovery_period_s:=0.2", "-p", "flush_period_s:=0.25"])
    wait_for_line(recorder, "recording to")
    publisher = processes.start([sys.executable, str(PROBE), "publish"])
    wait_for_line(recorder, "recording /probe/StepScore")
    time.sleep(3.0)
    killed_at = time.time_ns()
    os.killpg(recorder.pid, signal.SIGKILL)
    recorder.wait()
    processes.interrupt(publisher)
    assert not (bag / "metadata.yaml").exists()
    stream = BagStream(bag)
    store = typestore()
    expected = {name: sample_values(store, name, k) for k, name in enumerate(sorted(msg_files()))}
    stamps = []
    for item in stream.messages():
        if item.topic.startswith("/probe/"):
            stamps.append(item.log_time)
            message = from_any(store.deserialize_cdr(item.data, item.msgtype))
            assert differences(expected[item.msgtype], message) == [], item.msgtype
    assert not stream.stats.complete and stream.stats.chunks >= 8
    lost_s = (killed_at - max(stamps)) / 1e9
    rate = len(stamps) / ((max(stamps) - min(stamps)) / 1e9)
    print(f"SIGKILL: last recorded message {lost_s:.3f} s before the kill (flush period 0.25 s); "
          f"~{lost_s * rate:.0f} of ~{rate:.0f} messages/s lost; {len(stamps)} kept in {stream.stats.chunks} chunks")
    assert lost_s < 1.0


def test_recorder_lists_the_offered_qos(processes, tmp_path):
    bag = tmp_path / "bag"
    recorder = processes.start([ROS2RUN, "m2h_ros", "recorder_node", "--ros-args", "-p", f"output:={bag}",
                                "-p", "discovery_period_s:=0.2"])
    wait_for_line(recorder, "recording to")
    publisher = processes.start([sys.executable, str(PROBE), "publish"])
    wait_for_line(recorder, "recording /probe/StepScore")
    time.sleep(0.5)
    assert processes.interrupt(recorder)[0] == 0
    processes.interrupt(publisher)
    info = yaml.safe_load((bag / "metadata.yaml").read_text())["rosbag2_bagfile_information"]
    probe = next(t["topic_metadata"] for t in info["topics_with_message_count"]
                 if t["topic_metadata"]["name"] == "/probe/StepScore")
    assert probe["type_description_hash"] == typestore().hash_rihs01("m2h_msgs/msg/StepScore")
    # The probe publishes with the STEP profile; discovery does not carry history and depth (rosbag2
    # records the same "unknown", 0).
    (offered,) = probe["offered_qos_profiles"]
    assert (offered["reliability"], offered["durability"]) == ("reliable", "transient_local")
