#!/usr/bin/env python3
"""Publish a stereo recording as a live binaural microphone would: 1 s BinauralAudio frames on
`audio`, at real-time rate (``--speed`` plays faster), and optionally record what the separator
sends back on `separator/audio` into a file (stereo for its default binaural listener output, mono for
``audio_channels:=mono`` or the refined output).

    ros2run m2h_ros separator_node --ros-args -p target_class:=speech &
    python scripts/play_binaural.py recording.wav --listen separated.wav

The file is resampled to 16 kHz (the separator's rate) and cut into 1 s frames (the last one
zero-padded); frames carry episode id ``live/<file name>`` and step 0, 1, 2, ... so the separator's
memory carries over the whole file. With ``--listen`` the program waits (up to ``--timeout`` s) for
every frame's answer, writes them in order at the input's rate, and exits 0.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np
import rclpy
import soundfile as sf
from m2h_msgs.msg import BinauralAudio
from rclpy.node import Node

from m2h_ros import topics
from m2h_ros.core.audio.stft import DEFAULT_STFT
from m2h_ros.errors import AudioError
from m2h_ros.ros import convert
from m2h_ros.ros.qos import STEP
from m2h_ros.separate_cli import _resample, _write, check_stereo


def frames_of(path: Path) -> tuple[np.ndarray, int, int]:
    """(n, 2, 16000) float32 frames of a stereo file, its sample rate and its length in samples."""
    try:
        audio, rate = sf.read(path, dtype="float32", always_2d=True)
    except (sf.LibsndfileError, RuntimeError, OSError) as exc:
        raise AudioError(f"cannot read {path}: {exc}") from exc
    check_stereo(audio)
    audio = _resample(audio, rate, DEFAULT_STFT.sample_rate)
    frame = DEFAULT_STFT.clip_samples
    n = -(-audio.shape[0] // frame)
    padded = np.zeros((n * frame, 2), np.float32)
    padded[: audio.shape[0]] = audio
    return padded.reshape(n, frame, 2).transpose(0, 2, 1).copy(), rate, len(audio)


class Player(Node):
    def __init__(self, frames: np.ndarray, episode_id: str, *, speed: float, listen: bool):
        super().__init__("binaural_player")
        self.frames, self.episode_id, self.listen = frames, episode_id, listen
        self.pub = self.create_publisher(BinauralAudio, topics.AUDIO, STEP)
        self.answers: dict[int, np.ndarray] = {}
        if listen:
            self.create_subscription(BinauralAudio, topics.SEPARATED_AUDIO, self.on_answer, STEP)
        self.next = 0
        self.period = 1.0 / speed

    def on_answer(self, msg: BinauralAudio) -> None:
        if msg.episode_id == self.episode_id:
            channels = msg.channels if msg.channels in (1, 2) else 1  # anything else: audio_from_msg names it
            self.answers[msg.step] = convert.audio_from_msg(msg, sample_rate=DEFAULT_STFT.sample_rate,
                                                            samples=DEFAULT_STFT.clip_samples, channels=channels)

    def publish_next(self) -> None:
        msg = convert.audio_msg(self.frames[self.next], sample_rate=DEFAULT_STFT.sample_rate,
                                episode_id=self.episode_id, step=self.next,
                                stamp_ns=self.get_clock().now().nanoseconds)
        self.pub.publish(msg)
        self.next += 1


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("input", type=Path, help="stereo wav/flac (left, right ear)")
    parser.add_argument("--listen", type=Path, help="write the separator's answers to this file")
    parser.add_argument("--speed", type=float, default=1.0, help="playback speed (1 = real time)")
    parser.add_argument("--timeout", type=float, default=30.0, help="seconds to wait for a subscriber / answers")
    args = parser.parse_args(argv)
    try:
        frames, rate, length = frames_of(args.input)
    except AudioError as exc:
        print(f"play_binaural: error: {exc}", file=sys.stderr)
        return 2
    rclpy.init()
    node = Player(frames, f"live/{args.input.name}", speed=args.speed, listen=args.listen is not None)
    try:
        deadline = time.monotonic() + args.timeout
        while node.pub.get_subscription_count() == 0 or (node.listen and node.count_publishers(
                topics.SEPARATED_AUDIO) == 0):
            if time.monotonic() > deadline:
                print("play_binaural: error: no separator subscribed to audio", file=sys.stderr)
                return 2
            rclpy.spin_once(node, timeout_sec=0.1)
        time.sleep(0.5)  # let the endpoints match
        started = time.monotonic()
        while node.next < len(frames):
            node.publish_next()
            due = started + node.next * node.period
            while time.monotonic() < due:
                rclpy.spin_once(node, timeout_sec=max(0.0, due - time.monotonic()))
        if node.listen:
            deadline = time.monotonic() + args.timeout
            while len(node.answers) < len(frames) and time.monotonic() < deadline:
                rclpy.spin_once(node, timeout_sec=0.1)
            missing = sorted(set(range(len(frames))) - set(node.answers))
            if missing:
                print(f"play_binaural: error: no answer for frames {missing}", file=sys.stderr)
                return 1
            heard = np.concatenate([node.answers[k] for k in range(len(frames))], axis=-1).T[:length]
            heard = _resample(heard, DEFAULT_STFT.sample_rate, rate)
            _write(args.listen, heard[:, 0] if heard.shape[1] == 1 else heard, rate)
            print(f"play_binaural: {len(frames)} frames separated -> {args.listen}")
        return 0
    finally:
        node.destroy_node()
        rclpy.try_shutdown()


if __name__ == "__main__":
    sys.exit(main())
