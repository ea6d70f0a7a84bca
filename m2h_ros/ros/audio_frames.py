"""Publishing a live audio stream as the pipeline's frames: what the capture node and the audio_common
adapter share (core.audio.framing cuts the frames; this numbers and publishes them)."""

from __future__ import annotations

import numpy as np
from m2h_msgs.msg import BinauralAudio
from rclpy.node import Node

from m2h_ros import topics
from m2h_ros.core.audio.framing import FrameLayout, Framer
from m2h_ros.core.audio.stft import DEFAULT_STFT
from m2h_ros.ros import convert
from m2h_ros.ros.qos import STEP, publisher_events


class FramePublisher:
    """Blocks of a stream in, BinauralAudio frames out on `audio` (episode ``episode_id``, steps 0, 1,
    ...), at the separator's 16 kHz. ``gap()`` after lost samples: the frames begun are dropped."""

    def __init__(self, node: Node, *, input_rate: int, channels: int, frame_s: float, hop_s: float,
                 episode_id: str):
        self.layout = FrameLayout.of(input_rate=input_rate, output_rate=DEFAULT_STFT.sample_rate,
                                     frame_s=frame_s, hop_s=hop_s)
        self.framer = Framer(self.layout, channels)
        self.episode_id = episode_id
        self.pub = node.create_publisher(BinauralAudio, topics.AUDIO, STEP,
                                         event_callbacks=publisher_events(node.get_logger(), topics.AUDIO))
        self.published = 0
        self.dropped_frames = 0

    def gap(self) -> None:
        self.dropped_frames += self.framer.restart()

    def push(self, block: np.ndarray, stamp_ns: int) -> None:
        for frame in self.framer.push(block, stamp_ns):
            self.pub.publish(convert.audio_msg(frame.samples, sample_rate=self.layout.output_rate,
                                               episode_id=self.episode_id, step=self.published,
                                               stamp_ns=frame.stamp_ns))
            self.published += 1
