"""audio_common_adapter: a stream of ros-drivers' audio_common_msgs (as audio_capture publishes it with
format:=wave) becomes the pipeline's frames: the picked channels, resampled to 16 kHz as one recording,
stamped from the blocks' headers, never spliced across lost blocks. The interface is the released one:
the type hashes of the audio_common_msgs this workspace runs with equal those computed from the released
definitions by an independent implementation (rosbags) and pinned here."""

from __future__ import annotations

import json
import time
from pathlib import Path

import numpy as np
import pytest
import rclpy
import scipy.signal
from ament_index_python.packages import get_package_share_directory
from audio_common_msgs.msg import AudioData, AudioDataStamped, AudioInfo
from m2h_msgs.msg import BinauralAudio
from pipeline_helpers import node_args
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node
from rosbags.typesys import Stores, get_typestore, get_types_from_msg

from m2h_ros.ros import convert
from m2h_ros.ros.qos import STEP

pytestmark = pytest.mark.graph
ROOT = Path(__file__).resolve().parents[2]
RELEASED = ROOT / "third_party" / "audio_common_msgs" / "msg"
# RIHS01 of ros-drivers' audio_common_msgs (ros2 branch definitions, as released for Jazzy).
RELEASED_HASHES = {
    "AudioData": "RIHS01_a9742fba1567e649bbdba6ae034a72c7ef129b97c7a4da50fd2f3e1bfd8ffa86",
    "AudioDataStamped": "RIHS01_6fc679d5a868ed68e4d301f1ef42abecc86140afb57d255656ff2d9e476ea9e3",
    "AudioInfo": "RIHS01_b3494d204e513d2cceefae1888e5be3da7c8c8ca31eb277f7b5b62f364bcb1fb",
}
RATE, CHANNELS, PICK, BLOCK = 44100, 3, (2, 0), 441  # 10 ms blocks


@pytest.mark.parametrize("name", sorted(RELEASED_HASHES))
def test_the_interface_hashes_as_the_released_package(name):
    store = get_typestore(Stores.ROS2_JAZZY)
    types = {}
    for path in RELEASED.glob("*.msg"):
        types.update(get_types_from_msg(path.read_text(), f"audio_common_msgs/msg/{path.stem}"))
    store.register(types)
    assert store.hash_rihs01(f"audio_common_msgs/msg/{name}") == RELEASED_HASHES[name]
    # ... and the package this workspace runs with (built from those files, or a distro's) says the same
    built = Path(get_package_share_directory("audio_common_msgs")) / "msg" / f"{name}.json"
    assert json.loads(built.read_text())["type_hashes"][0]["hash_string"] == RELEASED_HASHES[name]


def test_a_wave_stream_becomes_stamped_frames_and_a_lost_stretch_is_never_spliced(processes):
    rng = np.random.default_rng(3)
    pcm = (rng.standard_normal((RATE * 5, CHANNELS)) * 6000).clip(-32768, 32767).astype("<i2")  # 5 s, S16LE
    lost = range(260, 300)  # blocks 2.6 s to 3.0 s never sent
    context = rclpy.Context()
    rclpy.init(context=context)
    node = Node("audio_capture_stand_in", context=context)
    executor = SingleThreadedExecutor(context=context)
    executor.add_node(node)
    frames = []
    node.create_subscription(BinauralAudio, "audio", frames.append, STEP)
    pub_info = node.create_publisher(AudioInfo, "mic/audio_info", 1)
    pub_audio = node.create_publisher(AudioDataStamped, "mic/audio_stamped", 10)
    proc = processes.start(node_args("audio_common_adapter", audio_topic="mic/audio_stamped",
                                     info_topic="mic/audio_info", channels=list(PICK), hop_s=0.5,
                                     episode_id="live/audio_common"))
    try:
        deadline = time.monotonic() + 60
        # (its `audio` publisher comes with the first AudioInfo; frames are transient-local: none is missed)
        while (pub_audio.get_subscription_count() == 0 or pub_info.get_subscription_count() == 0) \
                and time.monotonic() < deadline:
            executor.spin_once(timeout_sec=0.1)
        assert pub_audio.get_subscription_count() and pub_info.get_subscription_count(), "adapter never matched"
        info = AudioInfo(channels=CHANNELS, sample_rate=RATE, sample_format="S16LE", bitrate=RATE * 16 * CHANNELS,
                         coding_format="wave")
        # Its `audio` publisher appears once it has the AudioInfo: by then the stream's reader has matched too.
        while node.count_publishers("audio") == 0 and time.monotonic() < deadline:
            pub_info.publish(info)
            executor.spin_once(timeout_sec=0.2)
        time.sleep(0.5)
        start_ns = 1_700_000_000 * 10**9
        for k in range(len(pcm) // BLOCK):
            if k % 50 == 0:
                pub_info.publish(info)  # audio_capture repeats it (every 5 s)
            if k in lost:
                continue
            msg = AudioDataStamped(audio=AudioData(data=pcm[k * BLOCK:(k + 1) * BLOCK].tobytes()))
            msg.header.stamp = convert.stamp_of(start_ns + k * BLOCK * 10**9 // RATE)
            pub_audio.publish(msg)
            executor.spin_once(timeout_sec=0.003)
        deadline = time.monotonic() + 30
        while len(frames) < 6 and time.monotonic() < deadline:
            executor.spin_once(timeout_sec=0.1)
    finally:
        code, out, err = processes.interrupt(proc)
        executor.shutdown()
        node.destroy_node()
        context.try_shutdown()
    assert code == 0, err
    assert "1 gaps" in out and "0 blocks before" in out, out

    signal = pcm[:, list(PICK)].T.astype(np.float32) / 2**15
    up, down = 160, 441
    # Before the gap: frames 0..3 (0-1 s ... 1.5-2.5 s) are the whole recording resampled; 2-3 s and 2.5-3.5 s
    # spanned the gap and were dropped.
    whole = scipy.signal.resample_poly(signal, up, down, axis=1)
    # After it: the stream restarts at block 300 (3.0 s), resampled from there.
    after = scipy.signal.resample_poly(signal[:, 300 * BLOCK:], up, down, axis=1)
    starts = [0.0, 0.5, 1.0, 1.5, 3.0, 3.5]
    assert [f.step for f in frames] == list(range(len(frames))) and len(frames) == 6
    for frame, start in zip(frames, starts):
        assert (frame.episode_id, frame.channels, frame.sample_rate) == ("live/audio_common", 2, 16000)
        assert convert.nanoseconds_of(frame.header.stamp) == start_ns + round(start * 1e9)
        got = convert.audio_from_msg(frame, sample_rate=16000, samples=16000)
        source, offset = (whole, start) if start < 2.5 else (after, start - 3.0)
        first = round(offset * 16000)
        np.testing.assert_allclose(got, source[:, first:first + 16000], atol=1e-5)
