"""capture_node through the real audio stack: the node process opens an ALSA capture device through
sounddevice and PortAudio like any sound card; the device (m2h_ros/io/virtual_mic.py) plays a known
4-channel 48 kHz signal at real-time pace. The published frames must hold that signal's picked
channels, resampled to 16 kHz exactly as an offline resampling of the whole recording, stamped with
the capture time of their first sample; lost samples are counted and never spliced into a frame."""

from __future__ import annotations

import os
import signal
import subprocess
import time

import numpy as np
import pytest
import rclpy
import scipy.signal
from diagnostic_msgs.msg import DiagnosticArray
from m2h_msgs.msg import BinauralAudio
from pipeline_helpers import ROS2RUN, node_args
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node

from m2h_ros.io.virtual_mic import virtual_mic
from m2h_ros.ros import convert
from m2h_ros.ros.qos import STEP

pytestmark = pytest.mark.graph
RATE = 48000
SECONDS = 6.0
PICK = (2, 0)  # device channels -> left, right: order and choice both checked
HOP_S = 0.5


def known_signal() -> np.ndarray:
    """Broadband noise, a different draw per channel plus a tone on each: any mix-up of channels,
    offsets or resampling shows."""
    rng = np.random.default_rng(7)
    t = np.arange(int(RATE * SECONDS)) / RATE
    tones = np.stack([np.sin(2 * np.pi * (300 + 200 * c) * t) for c in range(4)], axis=1)
    return (0.2 * rng.standard_normal(tones.shape) + 0.3 * tones).astype(np.float32)


@pytest.fixture
def mic(tmp_path):
    signal_ = known_signal()
    return virtual_mic(tmp_path / "mic", signal_, RATE), signal_


@pytest.fixture
def listener():
    """(executor, received frames with their arrival time, diagnostics) in a context of its own."""
    context = rclpy.Context()
    rclpy.init(context=context)
    node = Node("live_audio_listener", context=context)
    executor = SingleThreadedExecutor(context=context)
    executor.add_node(node)
    frames, diagnostics = [], []
    node.create_subscription(BinauralAudio, "audio", lambda m: frames.append((m, time.time_ns())), STEP)
    node.create_subscription(DiagnosticArray, "/diagnostics", diagnostics.append, 10)
    yield executor, frames, diagnostics
    executor.shutdown()
    node.destroy_node()
    context.try_shutdown()


def spin_until(executor, done, timeout: float) -> None:
    deadline = time.monotonic() + timeout
    while not done() and time.monotonic() < deadline:
        executor.spin_once(timeout_sec=0.05)
    assert done(), "timed out"


def start_capture(processes, vm, **params):
    args = node_args("capture_node", device=vm.name, channels=list(PICK), sample_rate=RATE, hop_s=HOP_S,
                     episode_id="live/test", diagnostics_period_s=0.5, **params)
    return processes.start(args, env={**os.environ, **vm.env()})


def expected_frames(signal_: np.ndarray, start: int = 0) -> np.ndarray:
    """The picked channels from input sample ``start`` on, resampled as one recording: (2, n) at 16 kHz."""
    return scipy.signal.resample_poly(signal_[start:, list(PICK)].T, 1, 3, axis=1)


def samples(msg) -> np.ndarray:
    return convert.audio_from_msg(msg, sample_rate=16000, samples=16000)


def values(status) -> dict[str, str]:
    return {kv.key: kv.value for kv in status.values}


def test_frames_carry_the_picked_channels_resampled_and_stamped_at_capture_time(mic, listener, processes):
    vm, signal_ = mic
    executor, frames, diagnostics = listener
    proc = start_capture(processes, vm)
    spin_until(executor, lambda: len(frames) >= 9 and diagnostics, timeout=40)
    code, out, err = processes.interrupt(proc)
    assert code == 0, err
    assert "0 overruns, 0 lost blocks, 0 dropped frames" in out

    want = expected_frames(signal_)
    (start_ns,) = vm.starts_ns()
    for k, (msg, arrived_ns) in enumerate(frames[:9]):
        assert (msg.episode_id, msg.step, msg.sample_rate, msg.channels) == ("live/test", k, 16000, 2)
        np.testing.assert_allclose(samples(msg), want[:, k * 8000: k * 8000 + 16000], atol=2e-6)
        stamp = convert.nanoseconds_of(msg.header.stamp)
        # The first sample's capture time: the device delivered input sample i at start + i / rate.
        assert abs(stamp - (start_ns + k * HOP_S * 1e9)) < 30e6, (k, (stamp - start_ns) / 1e9)
        assert arrived_ns >= stamp + 1e9, "a frame was published before its last sample was captured"
    status = diagnostics[-1].status[0]
    assert status.name == "capture_node: audio input" and status.hardware_id == vm.name
    assert values(status)["overruns"] == "0" and values(status)["dropped_frames"] == "0"


def test_a_stalled_node_counts_the_overrun_and_never_splices_across_the_gap(mic, listener, processes):
    vm, signal_ = mic
    executor, frames, diagnostics = listener
    proc = start_capture(processes, vm, queue_s=0.1)
    spin_until(executor, lambda: len(frames) >= 2, timeout=40)
    os.kill(proc.pid, signal.SIGSTOP)  # every thread stops: the device runs on, its buffer overflows
    time.sleep(1.2)
    os.kill(proc.pid, signal.SIGCONT)
    spin_until(executor, lambda: any(values(d.status[0])["overruns"] != "0" for d in diagnostics), timeout=20)
    last_step = len(frames)
    spin_until(executor, lambda: len(frames) >= last_step + 3, timeout=20)
    code, out, err = processes.interrupt(proc)
    assert code == 0, err

    warned = [d.status[0] for d in diagnostics if values(d.status[0])["overruns"] != "0"]
    assert warned[0].level == warned[0].WARN and int(values(warned[-1])["dropped_frames"]) >= 1
    # Every frame, before and after the gap, is a contiguous piece of the signal starting where its
    # stamp says (to 5 ms): a frame spliced across the gap would match no single offset.
    (start_ns,) = vm.starts_ns()
    # (a reader the writer lost during the stall may get the transient-local history again: by step)
    frames = list({msg.step: (msg, arrived) for msg, arrived in frames}.values())
    assert [msg.step for msg, _ in frames] == list(range(len(frames)))
    signal_ = np.concatenate([signal_, np.zeros((2 * RATE, signal_.shape[1]), np.float32)])  # then silence
    full = expected_frames(signal_)
    resumed = False
    for msg, _ in frames:
        stamp_s = (convert.nanoseconds_of(msg.header.stamp) - start_ns) / 1e9
        got = samples(msg)
        # Locate the frame in the signal (16 kHz correlation, then the exact 48 kHz sample) ...
        j = int(np.argmax(np.correlate(full[0], got[0], mode="valid")))
        errors = {o: np.abs(got - expected_frames(signal_, o)[:, :16000])[:, 200:-200].max()
                  for o in range(max(3 * j - 3, 0), 3 * j + 4)}
        start = min(errors, key=errors.get)
        assert errors[start] < 1e-4, (msg.step, stamp_s, errors[start])
        # ... where its stamp says it began.
        assert abs(start / RATE - stamp_s) < 0.03, (msg.step, stamp_s, start / RATE)
        resumed |= start % round(HOP_S * RATE) != 0
    assert resumed, "no frame came from after the gap"


def test_list_devices_shows_the_virtual_microphone(mic):
    vm, _ = mic
    result = subprocess.run([ROS2RUN, "m2h_ros", "capture_node", "--list-devices"], capture_output=True, text=True,
                            env={**os.environ, **vm.env()}, timeout=60)
    assert result.returncode == 0, result.stderr
    assert f"{vm.name}  (ALSA, 4 in, {RATE} Hz)" in result.stdout


def test_a_missing_device_is_named_with_what_there_is(mic, tmp_path):
    vm, _ = mic
    result = subprocess.run(node_args("capture_node", device="no_such_microphone"), capture_output=True, text=True,
                            env={**os.environ, **vm.env()}, timeout=60)
    assert result.returncode == 2
    assert "MicrophoneError: no input device(s) match 'no_such_microphone'" in result.stderr
    assert vm.name in result.stderr
    # A machine without any capture device: ALSA's own configuration only, and no sound card.
    result = subprocess.run(node_args("capture_node"), capture_output=True, text=True, timeout=60,
                            env={**os.environ, "ALSA_CONFIG_PATH": vm.env()["ALSA_CONFIG_PATH"].split(":")[0]})
    assert result.returncode == 2
    assert "no audio input device found" in result.stderr
