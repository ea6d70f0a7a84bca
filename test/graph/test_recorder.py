"""recorder_node records what crosses the graph; SIGINT leaves a readable bag with every message intact;
SIGKILL loses at most about one flush period of messages, counted against what was sent."""

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


# The README's claim: a SIGKILL loses at most about the recorder's flush period of messages (its default,
# params/recorder_node.yaml). MARGIN covers delivery and the flush timer's lateness on busy cores.
FLUSH_PERIOD_S, MARGIN_S = 0.25, 0.25
# Sends StepScore k with its send time (ns) in the header at about 200 Hz; on SIGINT writes "k time" lines.
PUBLISH_NUMBERED = """
import sys, time, rclpy
from m2h_msgs.msg import StepScore
from m2h_ros.ros.qos import STEP
rclpy.init()
node = rclpy.create_node("numbered_publisher")
pub = node.create_publisher(StepScore, "numbered", STEP)
sent = []
try:
    while True:
        now = time.time_ns()
        msg = StepScore(episode_id="numbered", step=len(sent))
        msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(now, 10**9)
        pub.publish(msg)
        sent.append(now)
        time.sleep(0.005)
except KeyboardInterrupt:
    pass
finally:
    with open(sys.argv[1], "w") as out:
        out.writelines(f"{k} {t}\\n" for k, t in enumerate(sent))
"""


def test_recorder_sigkill_loses_at_most_about_a_flush_period(processes, tmp_path):
    bag = tmp_path / "bag"
    recorder = processes.start([ROS2RUN, "m2h_ros", "recorder_node", "--ros-args", "-p", f"output:={bag}",
                                "-p", "discovery_period_s:=0.2"])
    wait_for_line(recorder, "recording to")
    publisher = processes.start([sys.executable, "-c", PUBLISH_NUMBERED, str(tmp_path / "sent.txt")])
    wait_for_line(recorder, "recording /numbered")
    time.sleep(2.0)
    # Kill well after a flush (seen as the file growing): the worst case for a period longer than claimed,
    # any phase for the one claimed.
    (mcap,) = bag.glob("*.mcap")
    size = mcap.stat().st_size
    while mcap.stat().st_size == size:
        time.sleep(0.002)
    time.sleep(2.4 * FLUSH_PERIOD_S)
    killed_at = time.time_ns()
    os.killpg(recorder.pid, signal.SIGKILL)
    recorder.wait()
    processes.interrupt(publisher)
    assert not (bag / "metadata.yaml").exists()
    sent = {int(k): int(t) for k, t in (line.split() for line in (tmp_path / "sent.txt").read_text().splitlines())}
    stream = BagStream(bag)
    store = typestore()
    recorded = set()
    for item in stream.messages():
        if item.topic == "/numbered":
            message = store.deserialize_cdr(item.data, item.msgtype)
            stamp = message.header.stamp.sec * 10**9 + message.header.stamp.nanosec
            assert sent[message.step] == stamp  # intact
            recorded.add(message.step)
    assert not stream.stats.complete and len(recorded) > 200
    # Lost: sent after the first recorded (what came before the recorder subscribed never reached it) and
    # before the kill, and not in the bag.
    lost = sorted(k for k, t in sent.items() if min(recorded) < k and t < killed_at and k not in recorded)
    oldest_lost_s = (killed_at - sent[lost[0]]) / 1e9 if lost else 0.0
    print(f"SIGKILL: {len(lost)} of {len(recorded) + len(lost)} messages sent before the kill lost, the oldest "
          f"sent {oldest_lost_s:.3f} s before it (flush period {FLUSH_PERIOD_S} s); {stream.stats.chunks} chunks")
    assert oldest_lost_s <= FLUSH_PERIOD_S + MARGIN_S


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


def stale_audio_info_env(tmp_path) -> dict[str, str]:
    """The environment with a stale audio_common_msgs AudioInfo.msg (two fields of the released five)
    first on AMENT_PREFIX_PATH."""
    stale = tmp_path / "stale" / "share" / "audio_common_msgs" / "msg"
    stale.mkdir(parents=True)
    (stale / "AudioInfo.msg").write_text("uint8 channels\nuint32 sample_rate\n")
    return {**os.environ, "AMENT_PREFIX_PATH": f"{tmp_path / 'stale'}:{os.environ['AMENT_PREFIX_PATH']}"}


def test_a_definition_that_differs_from_the_publishers_is_named(processes, tmp_path):
    """A driver's type is recorded with its installed package's definition; where that is not the one the
    publisher was built with (here a stale AudioInfo.msg first on AMENT_PREFIX_PATH), the recorder warns,
    naming both hashes, and still records; the matching types pass without a word."""
    bag = tmp_path / "bag"
    recorder = processes.start([ROS2RUN, "m2h_ros", "recorder_node", "--ros-args", "-p", f"output:={bag}",
                                "-p", "discovery_period_s:=0.2"], env=stale_audio_info_env(tmp_path))
    wait_for_line(recorder, "recording to")
    driver = processes.start([sys.executable, str(Path(__file__).with_name("audio_capture_stand_in.py"))])
    log = ""
    for line in ("recording /audio/audio_info", "recording /audio/audio_stamped"):  # in either order
        if line not in log:
            log += "".join(wait_for_line(recorder, line))
    time.sleep(0.5)
    assert processes.interrupt(recorder)[0] == 0
    processes.interrupt(driver)
    assert "/audio/audio_info: the definition of audio_common_msgs/msg/AudioInfo recorded in the bag" in log, log
    assert "a reader of the bag will misread it" in log
    assert "/audio/audio_stamped: the definition" not in log and "/audio/audio: the definition" not in log
    info = yaml.safe_load((bag / "metadata.yaml").read_text())["rosbag2_bagfile_information"]
    assert "/audio/audio_info" in {t["topic_metadata"]["name"] for t in info["topics_with_message_count"]}


def test_an_existing_bag_is_named_with_what_each_startup_takes(processes, tmp_path):
    (tmp_path / "bag").mkdir()
    recorder = processes.start([ROS2RUN, "m2h_ros", "recorder_node", "--ros-args", "-p", f"output:={tmp_path / 'bag'}"])
    _, err = recorder.communicate(timeout=60)
    assert recorder.returncode == 2
    assert "already exists: choose another output, or replace it with overwrite:=true (ros2 launch)" in err
    assert "-p overwrite:=true (ros2 run)" in err and "--set recorder_node.overwrite=true" in err


def test_topics_exclusions_rate_limits_and_zstd_chunks(processes, tmp_path):
    """What ros2 bag record offers: only the topics asked for (a pattern), some left out, one at a limited
    rate; the chunks zstd-compressed, which Foxglove's reader (mcap + mcap-ros2-support), rosbags and this
    project's own reader (m2h-eval's) all decode."""
    from mcap.reader import make_reader
    from mcap_ros2.decoder import DecoderFactory

    bag = tmp_path / "bag"
    recorder = processes.start([ROS2RUN, "m2h_ros", "recorder_node", "--ros-args", "-p", f"output:={bag}",
                                "-p", "discovery_period_s:=0.2", "-p", "topics:=[/probe/*]",
                                "-p", "exclude:=[/probe/AgentPose,/probe/Spectrogram]",
                                "-p", "max_rate_hz:=[/probe/EpisodeInfo=2]", "-p", "compression:=zstd"])
    wait_for_line(recorder, "recording to")
    publisher = processes.start([sys.executable, str(PROBE), "publish"])
    wait_for_line(recorder, "recording /probe/StepScore")  # the last type the probe advertises
    started = time.monotonic()
    time.sleep(3.0)  # 10 Hz per topic
    code, _, err = processes.interrupt(recorder)
    recorded_for = time.monotonic() - started
    processes.interrupt(publisher)
    assert code == 0, err
    assert "left out by rate limits: /probe/EpisodeInfo" in err
    counts: dict[str, int] = {}
    for item in read_messages(bag):  # rosbags
        counts[item.topic] = counts.get(item.topic, 0) + 1
    probes = {f"/probe/{path.stem}" for path in msg_files().values()}
    assert set(counts) == probes - {"/probe/AgentPose", "/probe/Spectrogram"}  # no /rosout: not asked for
    assert counts["/probe/StepScore"] >= 20
    assert 1 <= counts["/probe/EpisodeInfo"] <= 2 * (recorded_for + 1.0) + 1  # 2 Hz of the probe's 10 Hz
    (mcap,) = bag.glob("*.mcap")
    with mcap.open("rb") as stream:
        reader = make_reader(stream, decoder_factories=[DecoderFactory()])
        assert {chunk.compression for chunk in reader.get_summary().chunk_indexes} == {"zstd"}
        decoded = sum(1 for _ in reader.iter_decoded_messages())
    assert decoded == sum(counts.values())
    assert sum(1 for _ in BagStream(bag).messages()) == decoded
