#!/usr/bin/env python3
"""Live separator latency through the graph: a microphone (the virtual ALSA capture device playing a
binaural recording at real-time pace) -> capture_node -> separator_node, measured from each frame's last
sample (its capture stamp + the frame length) to the moment its estimate on `separator/audio` reaches a
listener: p50 / p99. Beside it, in the same run: the capture path alone (last sample -> frame on
`audio`), the separator node's own time per frame and the real-time factor (that time / the new audio
each frame brings, the hop), the same f^B -> f^M -> f^R step timed in this process as a reference, and
the machine's load.

    python scripts/bench/live_latency.py [--seconds 60] [--hop 0.5] [--rate 48000]
"""

from __future__ import annotations

import argparse
import os
import re
import subprocess
import sys
import tempfile
import time
from pathlib import Path

os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")

import numpy as np  # noqa: E402
import rclpy  # noqa: E402
import torch  # noqa: E402
from m2h_msgs.msg import BinauralAudio  # noqa: E402
from rclpy.executors import SingleThreadedExecutor  # noqa: E402
from rclpy.node import Node  # noqa: E402

from m2h_ros import topics  # noqa: E402
from m2h_ros.io.virtual_mic import virtual_mic  # noqa: E402
from m2h_ros.models.checkpoint import DEFAULT_SEPARATOR_CHECKPOINT, load_separator  # noqa: E402
from m2h_ros.models.runner import SeparatorRunner  # noqa: E402
from m2h_ros.paths import REPO_DIR  # noqa: E402
from m2h_ros.ros import convert  # noqa: E402
from m2h_ros.ros.qos import STEP  # noqa: E402

ROS2RUN = str(REPO_DIR / "scripts" / "bin" / "ros2run")
WARM_UP = 3  # first estimates left out: the separator's first steps warm its caches


def recording(seconds: float, rate: int) -> np.ndarray:
    """(samples, 2): a speech-band stand-in, noise bursts and tones in both ears, the right one later."""
    rng = np.random.default_rng(0)
    n = int(seconds * rate)
    t = np.arange(n) / rate
    left = 0.2 * rng.standard_normal(n) * (0.5 + 0.5 * np.sin(2 * np.pi * 3 * t)) + 0.2 * np.sin(2 * np.pi * 220 * t)
    return np.stack([left, 0.8 * np.roll(left, rate // 2000)], axis=1).astype(np.float32)


def wait_for_ready(proc: subprocess.Popen, timeout: float = 120.0) -> str:
    """The process's output up to its "ready:" line (the nodes log it once they are set up)."""
    lines, deadline = [], time.monotonic() + timeout
    while time.monotonic() < deadline:
        line = proc.stdout.readline()
        if not line:
            raise SystemExit(f"{proc.args[2]} exited before it was ready:\n" + "".join(lines))
        lines.append(line)
        if "ready:" in line:
            return "".join(lines)
    raise SystemExit(f"{proc.args[2]} not ready within {timeout} s")


def in_process_step_ms(repeats: int = 50) -> float:
    """Median ms of one separator step on a 1 s frame, in this process, one torch thread."""
    torch.set_num_threads(1)
    loaded = load_separator(DEFAULT_SEPARATOR_CHECKPOINT)
    runner = SeparatorRunner(loaded, 1)
    frame = recording(1.0, 16000).T[None].copy()
    classes = runner.class_indices(["speech"])
    times = []
    for k in range(repeats):
        started = time.perf_counter()
        runner.step(frame, classes, np.array([k == 0])).waveform(frame, config=loaded.stft, output="masked_mixture")
        times.append(time.perf_counter() - started)
    return 1000 * float(np.median(times[5:]))


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=60.0, help="seconds of live audio")
    parser.add_argument("--hop", type=float, default=0.5, help="capture_node hop_s (a frame every HOP s)")
    parser.add_argument("--rate", type=int, default=48000, help="the virtual microphone's sample rate")
    args = parser.parse_args(argv)
    load_before = os.getloadavg()[0]
    with tempfile.TemporaryDirectory() as tmp:
        mic = virtual_mic(Path(tmp), recording(args.seconds + 30, args.rate), args.rate)
        env = {**os.environ, **mic.env()}
        separator = subprocess.Popen([ROS2RUN, "m2h_ros", "separator_node", "--ros-args", "-p", "target_class:=speech"],
                                     stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, env=env)
        # The microphone starts once the separator is up: their start-ups do not compete for the cores.
        started = [wait_for_ready(separator)]
        capture = subprocess.Popen([ROS2RUN, "m2h_ros", "capture_node", "--ros-args", "-p", f"device:={mic.name}",
                                    "-p", f"sample_rate:={args.rate}", "-p", f"hop_s:={args.hop}"],
                                   stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, env=env)
        started.append(wait_for_ready(capture))
        rclpy.init()
        node = Node("live_latency_listener")
        executor = SingleThreadedExecutor()
        executor.add_node(node)
        frame_at, estimate_at, stamps = {}, {}, {}

        def on_frame(msg: BinauralAudio) -> None:
            frame_at[msg.step] = time.time_ns()
            stamps[msg.step] = convert.nanoseconds_of(msg.header.stamp)

        node.create_subscription(BinauralAudio, topics.AUDIO, on_frame, STEP)
        node.create_subscription(BinauralAudio, topics.SEPARATED_AUDIO,
                                 lambda msg: estimate_at.setdefault(msg.step, time.time_ns()), STEP)
        try:
            deadline = time.monotonic() + 120 + args.seconds
            first = None
            while time.monotonic() < deadline:
                executor.spin_once(timeout_sec=0.05)
                if first is None and estimate_at:
                    first = time.monotonic()
                if first is not None and time.monotonic() - first > args.seconds:
                    break
                if separator.poll() is not None or capture.poll() is not None:
                    raise SystemExit("a node exited early:\n" + (separator.stdout.read() or "")
                                     + (capture.stdout.read() or ""))
        finally:
            for proc in (capture, separator):
                proc.send_signal(2)
            outputs = [before + proc.communicate(timeout=30)[0]
                       for before, proc in zip(reversed(started), (capture, separator))]
            node.destroy_node()
            rclpy.try_shutdown()
    load_after = os.getloadavg()[0]
    steps = sorted(set(estimate_at) & set(stamps))[WARM_UP:]
    if not steps:
        print("no estimates arrived:\n" + "\n".join(outputs), file=sys.stderr)
        return 1
    frame_ns = 1e9  # capture_node's frame_s
    to_estimate = np.array([(estimate_at[s] - stamps[s] - frame_ns) / 1e6 for s in steps])
    to_frame = np.array([(frame_at[s] - stamps[s] - frame_ns) / 1e6 for s in steps])
    node_ms = re.search(r"latency per step \(message in to all out\) p50 ([\d.]+) ms", outputs[1])
    capture_line = next((line for line in outputs[0].splitlines() if "frames published" in line), "")
    reference_ms = in_process_step_ms()
    print(f"live latency, {len(steps)} frames ({args.seconds:g} s of audio, hop {args.hop:g} s, "
          f"{args.rate} Hz virtual microphone), load {load_before:.1f} -> {load_after:.1f}, {os.cpu_count()} CPUs")
    print(f"  frame's last sample -> estimate on separator/audio: p50 {np.median(to_estimate):.0f} ms, "
          f"p99 {np.percentile(to_estimate, 99):.0f} ms, max {to_estimate.max():.0f} ms")
    print(f"  frame's last sample -> frame on audio (capture alone): p50 {np.median(to_frame):.0f} ms, "
          f"p99 {np.percentile(to_frame, 99):.0f} ms")
    if node_ms:
        step_ms = float(node_ms.group(1))
        print(f"  separator_node per frame (its own p50): {step_ms:.1f} ms; real-time factor "
              f"{step_ms / (1000 * args.hop):.3f} (per {args.hop:g} s of new audio)")
    print(f"  reference: the same separator step in this process (1 thread, p50): {reference_ms:.1f} ms")
    print(f"  {capture_line.strip()}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
