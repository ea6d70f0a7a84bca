"""audio_common_adapter: a robot that already publishes its microphones with ros-drivers' audio_common
(``audio_common_msgs/AudioDataStamped`` + ``AudioInfo``, the package released for Jazzy) feeds the
pipeline: the stream is decoded, the chosen channels resampled to 16 kHz and cut into the same
BinauralAudio frames the simulator and capture_node publish, each stamped with its first sample's time
(from the blocks' header stamps).

    ros2 run audio_capture audio_capture_node --ros-args -p format:=wave -p channels:=2 -p sample_rate:=48000
    ros2 run m2h_ros audio_common_adapter

Only uncompressed audio is read (``coding_format`` wave; sample formats of core.audio.pcm); mp3 is an
error naming the fix. mgonzs13's audio_common (``audio_common_msgs/AudioStamped``, a different type of
the same package name) is not supported. A block stamped later than the previous block's end (by
``gap_tolerance_s``) means samples were lost: the frames begun are dropped, none spans the gap.
"""

from __future__ import annotations

from audio_common_msgs.msg import AudioDataStamped, AudioInfo
from rclpy.node import Node

from m2h_ros.core.audio.pcm import decode_pcm
from m2h_ros.errors import AudioError
from m2h_ros.node_configs import AudioCommonAdapterConfig
from m2h_ros.ros import convert
from m2h_ros.ros.audio_frames import FramePublisher
from m2h_ros.ros.params import declare_config
from m2h_ros.ros.spin import run_node

UNCOMPRESSED = ("wave", "wav", "pcm", "raw")
INFO_FIELDS = ("channels", "sample_rate", "sample_format", "coding_format")


class AudioCommonAdapter(Node):
    def __init__(self):
        super().__init__("audio_common_adapter")
        self.config: AudioCommonAdapterConfig = declare_config(self, AudioCommonAdapterConfig)
        self.info: AudioInfo | None = None
        self.frames: FramePublisher | None = None  # made at the first AudioInfo: its rate sets the resampling
        self.next_ns: int | None = None            # where the next block should start, from the last one
        self.unannounced = self.gaps = 0
        # audio_capture's publishers: reliable, volatile, default depths
        self.create_subscription(AudioInfo, self.config.info_topic, self.on_info, 10)
        self.create_subscription(AudioDataStamped, self.config.audio_topic, self.on_audio, 100)
        self.get_logger().info(f"ready: reading {self.resolve_topic_name(self.config.audio_topic)} "
                               f"(audio_common_msgs/AudioDataStamped) once {self.config.info_topic} arrives")

    def on_info(self, msg: AudioInfo) -> None:
        if self.info is not None:
            if [getattr(msg, f) for f in INFO_FIELDS] != [getattr(self.info, f) for f in INFO_FIELDS]:
                raise AudioError(f"the stream's AudioInfo changed from {self._describe(self.info)} to "
                                 f"{self._describe(msg)}; restart the adapter")
            return
        if msg.coding_format.lower() not in UNCOMPRESSED:
            raise AudioError(f"{self.config.info_topic}: coding format {msg.coding_format!r}; the adapter reads "
                             f"uncompressed audio (audio_capture: -p format:=wave)")
        channels = self.config.channels
        if not channels or min(channels) < 0 or max(channels) >= msg.channels:
            raise AudioError(f"channels {list(channels)} of a stream with {msg.channels} channel(s) (0-based)")
        decode_pcm(b"", sample_format=msg.sample_format, channels=msg.channels)  # an unknown format fails now
        self.info = msg
        self.frames = FramePublisher(self, input_rate=msg.sample_rate, channels=len(channels),
                                     frame_s=self.config.frame_s, hop_s=self.config.hop_s,
                                     episode_id=self.config.episode_id)
        self.get_logger().info(f"stream: {self._describe(msg)}; publishing channels {list(channels)} as "
                               f"{self.frames.layout.output_rate} Hz frames on {self.frames.pub.topic_name}")

    def on_audio(self, msg: AudioDataStamped) -> None:
        if self.info is None:
            self.unannounced += 1
            return
        block = decode_pcm(bytes(msg.audio.data), sample_format=self.info.sample_format,
                           channels=self.info.channels)[list(self.config.channels)]
        stamp = convert.nanoseconds_of(msg.header.stamp)
        if self.next_ns is not None and stamp - self.next_ns > self.config.gap_tolerance_s * 1e9:
            self.gaps += 1
            self.frames.gap()
        self.next_ns = stamp + round(block.shape[1] * 1e9 / self.info.sample_rate)
        self.frames.push(block, stamp)

    @staticmethod
    def _describe(info: AudioInfo) -> str:
        return f"{info.channels} ch, {info.sample_rate} Hz, {info.sample_format}, {info.coding_format}"

    def destroy_node(self) -> None:
        published = self.frames.published if self.frames else 0
        dropped = self.frames.dropped_frames if self.frames else 0
        print(f"audio_common_adapter: {published} frames published, {self.gaps} gaps, {dropped} dropped frames, "
              f"{self.unannounced} blocks before the stream's AudioInfo", flush=True)
        super().destroy_node()


def main(args=None):
    run_node(AudioCommonAdapter, args)


if __name__ == "__main__":
    main()
