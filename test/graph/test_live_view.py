"""live_view_node serves a pipeline run (from the recorder's process) to a Foxglove WebSocket client (m2h_ros.io.foxglove_watch, a plain
`websockets` client speaking the protocol): every topic advertised as a ROS 2 channel with its message
definition, messages that decode with that definition alone and equal what the recorder wrote, the derived
TF tree, pcm-s16 audio, spectrogram pictures and path, made by the live view itself and equal to what
m2h-derive adds to the bag; a robot driver's own type (audio_common_msgs) with the definition from its
installed package; only what a client watches is subscribed to, so only that is built; bound to localhost;
a taken port is named."""

from __future__ import annotations

import asyncio
import socket
import struct
import subprocess
import sys
import time
from collections.abc import Iterator
from concurrent.futures import Future, ThreadPoolExecutor
from contextlib import contextmanager

import numpy as np
import pytest
import rclpy
from mcap_ros2._dynamic import generate_dynamic
from rclpy.context import Context
from rclpy.node import Node
from pipeline_helpers import ROOT, ROS2RUN, node_env, tiny_sets
from test_derived_topics import sent
from test_executables import wait_for_line
from test_recorder import stale_audio_info_env
from rosbags.rosbag2 import Reader

from m2h_ros.io.foxglove_watch import watch
from m2h_ros.io.msg_defs import typestore
from m2h_ros.io.derived import PCM_GAIN

pytestmark = pytest.mark.graph
# Messages the first client waits for on each topic (/tf_static is sent once, then on each subscription).
CHECKED = {"/audio": 3, "/odom": 3, "/scores/step": 3, "/audio/pcm": 3, "/separator/audio/pcm": 3, "/tf": 3,
           "/tf_static": 1, "/audio/audio_stamped": 3, "/spectrogram/mixture": 3, "/spectrogram/refined": 3,
           "/path": 3}
MADE_BY_THE_LIVE_VIEW = ("/audio/pcm", "/separator/audio/pcm", "/spectrogram/mixture", "/spectrogram/refined", "/path")
LATCHED = {"/map": 1, "/tf_static": 1, "/episode": 1}  # what a client that joins mid-episode gets at once


def free_port() -> int:
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        return sock.getsockname()[1]


def recorded(bag, topic: str) -> dict[bytes, int]:
    """The raw CDR payloads the recorder wrote for ``topic``, each with its index."""
    with Reader(bag) as reader:
        conns = [c for c in reader.connections if c.topic == topic]
        return {bytes(data): k for k, (_, _, data) in enumerate(reader.messages(connections=conns))}


def watched_run(processes, data_dir, out, *, episodes: int) -> tuple[int, subprocess.Popen]:
    """A tiny pipeline run at 2 steps/s with the live view on a free port: (the port, the run)."""
    port = free_port()
    processes.start([sys.executable, str(ROOT / "test" / "graph" / "audio_capture_stand_in.py")])
    run = subprocess.Popen([sys.executable, str(ROOT / "scripts" / "run_pipeline.py"), "--out", str(out),
                            "--episodes", str(episodes), "--controller", "random", "--mode", "free_running",
                            "--rate", "2", "--live-view", str(port), "--set", "live_view_node.discovery_period_s=0.1",
                            *tiny_sets()], stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
                           env=node_env(data_dir), cwd=ROOT)
    return port, run


def test_a_foxglove_client_watches_a_pipeline_run(small_library, small_data_dir, processes, tmp_path):
    # Free-running at 2 steps/s: two episodes last about 20 s, time for two clients to subscribe.
    # The probe joins the graph before the run: DDS discovery of a process can take seconds, longer than the
    # window in which the probe looks.
    with graph_probe() as probe:
        port, run = watched_run(processes, small_data_dir, tmp_path, episodes=2)
        try:
            first = asyncio.run(watch(port, wanted=CHECKED, timeout=180.0))
            listening = listening_addresses(port)  # while the run is surely still on (it ends some 20 s in)
            with ThreadPoolExecutor(1) as pool:  # who reads /audio while a client watches it
                watching = pool.submit(asyncio.run, watch(port, wanted={"/audio": 6}, timeout=60.0, only={"/audio"}))
                nodes, audio_readers = graph_of(probe, "/audio", while_running=watching)
                assert watching.result().counts["/audio"] >= 6
            late = asyncio.run(watch(port, wanted=LATCHED, timeout=5.0)).payloads  # the map went out steps ago
        finally:
            out, _ = run.communicate(timeout=240)
    assert run.returncode == 0, out
    assert f"live view: ws://127.0.0.1:{port}" in out
    assert listening == ["127.0.0.1"]  # the default binds to this machine only
    # Served from the recorder's process: a watched topic reaches the live view through the recorder's
    # subscription, with no second delivery from its publisher.
    assert {"live_view_node", "recorder_node"} <= nodes, nodes
    assert "recorder_node" in audio_readers and "live_view_node" not in audio_readers, audio_readers
    assert not (tmp_path / "logs" / "live_view_node.log").exists()
    assert "serving the graph to Foxglove" in (tmp_path / "logs" / "recorder_node.log").read_text()
    # The pictures, tracks and path are made by the live view from the raw topics: the nodes build none
    # of them, even for a client that watches everything.
    for node in ("separator_node", "evaluator_node", "sim_node"):
        counts = sent((tmp_path / "logs" / f"{node}.log").read_text())
        assert not any(count for topic, count in counts.items() if topic != "/tf"), (node, counts)
    store = typestore()
    channels, received = first.channels, first.payloads
    ros_topics = {"/audio", "/odom", "/agent_pose", "/episode", "/camera/rgb/image_raw", "/camera/depth/image_raw",
                  "/separator/refined", "/separator/audio", "/cmd", "/scores/step", "/ground_truth/target"}
    assert ros_topics <= set(channels), sorted(channels)
    for topic in ros_topics:
        channel = channels[topic]
        assert (channel["encoding"], channel["schemaEncoding"]) == ("cdr", "ros2msg"), topic
        assert channel["schema"] == store.generate_msgdef(channel["schemaName"], ros_version=2)[0], topic
    for topic, count in CHECKED.items():
        assert len(received.get(topic, ())) >= count, (topic, {t: len(m) for t, m in received.items()})
    for topic in LATCHED:  # the kept message: as the graph published it (or, for /tf_static, as derived)
        assert topic in late, (topic, {t: len(m) for t, m in late.items()})
        kept = received[topic] if topic == "/tf_static" else recorded(tmp_path / "bag", topic)
        assert late[topic][0] in kept, topic

    decode = {t: generate_dynamic(channels[t]["schemaName"], channels[t]["schema"])[channels[t]["schemaName"]]
              for t in CHECKED}
    audio = [decode["/audio"](payload) for payload in received["/audio"]]
    assert all(a.sample_rate == 16000 and a.channels == 2 and len(a.samples) == 2 * 16000 for a in audio)
    odom = [decode["/odom"](payload) for payload in received["/odom"]]
    assert all(o.child_frame_id == "base_link" and np.isfinite(o.pose.pose.position.x) for o in odom)
    scores = [decode["/scores/step"](payload) for payload in received["/scores/step"]]
    assert all(np.isfinite(s.si_sdr) and s.episode_id == audio[0].episode_id for s in scores)
    # byte for byte what the recorder wrote, and what m2h-derive added to the bag after the run
    for topic in ("/audio", "/odom", "/scores/step", *MADE_BY_THE_LIVE_VIEW):
        in_bag = recorded(tmp_path / "bag", topic)
        assert all(payload in in_bag for payload in received[topic]), topic

    # The derived topics, as the recorder writes them into the bag: a connected tree, audio to play.
    edges = {(t.header.frame_id, t.child_frame_id) for topic in ("/tf", "/tf_static")
             for payload in received[topic] for t in decode[topic](payload).transforms}
    assert edges == {("map", "odom"), ("odom", "base_link"), ("base_link", "head"), ("head", "camera")}
    assert channels["/audio/pcm"]["schemaName"] == "foxglove_msgs/msg/RawAudio"
    by_stamp = {(a.header.stamp.sec, a.header.stamp.nanosec): a for a in audio}
    matched = 0
    for payload in received["/audio/pcm"]:
        pcm = decode["/audio/pcm"](payload)
        assert (pcm.format, pcm.sample_rate, pcm.number_of_channels) == ("pcm-s16", 16000, 2)
        assert len(pcm.data) == 2 * 2 * 16000
        source = by_stamp.get((pcm.timestamp.sec, pcm.timestamp.nanosec))
        if source is not None:  # frames of (left, right) samples, scaled by the fixed gain
            heard = np.frombuffer(bytes(pcm.data), "<i2").reshape(-1, 2).T / 32767.0
            planar = np.asarray(source.samples, np.float32).reshape(2, -1)
            expected = np.clip(planar * PCM_GAIN, -1.0, 1.0)
            assert np.abs(heard - expected).max() < 1e-4 and np.abs(expected).max() > 0.05
            matched += 1
    assert matched >= 1
    separated = decode["/separator/audio/pcm"](received["/separator/audio/pcm"][0])  # the binaural listener output
    assert (separated.format, separated.number_of_channels, len(separated.data)) == ("pcm-s16", 2, 2 * 2 * 16000)
    # A type the project does not define, served with the definition its installed package has
    assert channels["/audio/audio_stamped"]["schemaName"] == "audio_common_msgs/msg/AudioDataStamped"
    blocks = [decode["/audio/audio_stamped"](payload) for payload in received["/audio/audio_stamped"]]
    assert all(len(b.audio.data) == 960 * 2 * 2 for b in blocks)  # 20 ms of 2 channels of S16 at 48 kHz


def test_the_nodes_build_only_what_a_client_watches(small_library, small_data_dir, processes, tmp_path):
    port, run = watched_run(processes, small_data_dir, tmp_path, episodes=1)
    try:
        # A client showing the odometry only: the live view subscribes to it (and the latched topics) alone.
        odometry = asyncio.run(watch(port, wanted={"/odom": 3}, timeout=120.0, only={"/odom"}))
    finally:
        out, _ = run.communicate(timeout=240)
    assert run.returncode == 0, out
    assert odometry.counts["/odom"] >= 3 and set(odometry.counts) == {"/odom"}
    assert {"/audio/pcm", "/tf", "/odom"} <= set(odometry.channels)  # offered, but only the odometry shown
    for node in ("separator_node", "evaluator_node", "sim_node"):
        counts = sent((tmp_path / "logs" / f"{node}.log").read_text())
        assert counts and not any(counts.values()), (node, counts)


@contextmanager
def graph_probe() -> Iterator[Node]:
    """A node of its own context that only looks at the graph (the rmw keeps its graph cache up to date
    without spinning)."""
    context = Context()
    rclpy.init(context=context)
    node = Node("graph_probe", context=context)
    try:
        yield node
    finally:
        node.destroy_node()
        rclpy.shutdown(context=context)


def graph_of(probe: Node, topic: str, *, while_running: Future) -> tuple[set[str], set[str]]:
    """The graph's node names and the names of the nodes subscribed to ``topic``, every one seen while
    ``while_running`` runs."""
    nodes: set[str] = set()
    readers: set[str] = set()
    while not while_running.done():
        nodes |= set(probe.get_node_names())
        readers |= {info.node_name for info in probe.get_subscriptions_info_by_topic(topic)}
        time.sleep(0.1)
    return nodes, readers


def listening_addresses(port: int) -> list[str]:
    """The local addresses with a TCP socket listening on ``port`` (from /proc/net/tcp and tcp6)."""
    found = []
    for table in ("/proc/net/tcp", "/proc/net/tcp6"):
        for line in open(table).read().splitlines()[1:]:
            local, state = line.split()[1], line.split()[3]
            address, hex_port = local.split(":")
            if int(hex_port, 16) == port and state == "0A":  # 0A: LISTEN
                found.append(socket.inet_ntoa(struct.pack("<I", int(address, 16))) if len(address) == 8
                             else f"ipv6:{address}")
    return found


@pytest.mark.parametrize("host", ["live_view_node", "recorder_node"])
def test_a_taken_port_stops_the_node_naming_it(processes, tmp_path, host):
    """Alone, or in the recorder's process, where it stops the recorder before a bag is created."""
    with socket.socket() as taken:
        taken.bind(("127.0.0.1", 0))
        taken.listen()
        port = taken.getsockname()[1]
        if host == "live_view_node":
            args = ["-p", f"port:={port}"]
        else:
            args = ["-p", "recorder_node:live_view:=true", "-p", f"recorder_node:output:={tmp_path / 'bag'}",
                    "-p", f"live_view_node:port:={port}"]
        proc = processes.start([ROS2RUN, "m2h_ros", host, "--ros-args", *args])
        _, err = proc.communicate(timeout=60.0)
    assert proc.returncode == 2, err
    assert f"LiveViewError: cannot serve on 127.0.0.1:{port}" in err and "Address already in use" in err
    assert not (tmp_path / "bag").exists()


def test_a_definition_that_differs_from_the_publishers_is_named(processes, tmp_path):
    """As the recorder: a stale installed AudioInfo.msg is served with a warning naming both hashes."""
    view = processes.start([ROS2RUN, "m2h_ros", "live_view_node", "--ros-args", "-p", f"port:={free_port()}",
                            "-p", "discovery_period_s:=0.2"], env=stale_audio_info_env(tmp_path))
    wait_for_line(view, "serving the graph")
    driver = processes.start([sys.executable, str(ROOT / "test" / "graph" / "audio_capture_stand_in.py")])
    log = ""
    for line in ("serving /audio/audio_info", "serving /audio/audio_stamped"):  # in either order
        if line not in log:
            log += "".join(wait_for_line(view, line))
    assert processes.interrupt(view)[0] == 0
    processes.interrupt(driver)
    assert "/audio/audio_info: the definition of audio_common_msgs/msg/AudioInfo served to Foxglove" in log, log
    assert "Foxglove will misread it" in log
    assert "/audio/audio_stamped: the definition" not in log
