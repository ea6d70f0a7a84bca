"""capture_node: a real microphone pair or array as the pipeline's audio: publishes the same
BinauralAudio frames the simulator does on `audio`, resampled to 16 kHz and stamped with the capture
time of each frame's first sample, and reports overruns and dropped frames on /diagnostics.

    ros2 run m2h_ros capture_node --list-devices
    ros2 run m2h_ros capture_node --ros-args -p device:=ReSpeaker -p channels:=[0,3] -p hop_s:=0.5

Frames carry the episode id ``episode_id`` and steps 0, 1, 2, ... . Samples lost before the node saw
them (a PortAudio overrun, or the node too far behind) restart the framing: no frame spans a gap, and
the frames begun before it are counted as dropped. A missing device ends the node with an error that
lists the devices PortAudio sees.
"""

from __future__ import annotations

import sys

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from rclpy.node import Node

from m2h_ros.errors import MicrophoneError
from m2h_ros.io.microphone import Microphone, device_listing, find_device
from m2h_ros.node_configs import CaptureNodeConfig
from m2h_ros.ros.audio_frames import FramePublisher
from m2h_ros.ros.params import declare_config
from m2h_ros.ros.spin import run_node

DIAGNOSTICS = "/diagnostics"  # absolute: diagnostic aggregators listen there, whatever the namespace


class CaptureNode(Node):
    def __init__(self):
        super().__init__("capture_node")
        self.config: CaptureNodeConfig = declare_config(self, CaptureNodeConfig)
        self.device = find_device(self.config.device)
        rate = self.config.sample_rate or self.device.default_rate
        self.frames = FramePublisher(self, input_rate=rate, channels=len(self.config.channels),
                                     frame_s=self.config.frame_s, hop_s=self.config.hop_s,
                                     episode_id=self.config.episode_id)
        self.pub_diagnostics = self.create_publisher(DiagnosticArray, DIAGNOSTICS, 10)
        self.reported = (0, 0, 0)  # overruns, lost blocks, dropped frames at the last report
        # PortAudio's thread only queues blocks and wakes the executor; framing and publishing run here.
        self.wake = self.create_guard_condition(self.on_blocks)
        self.create_timer(self.config.diagnostics_period_s, self.report)
        clock = self.get_clock()
        self.mic = Microphone(self.device, channels=self.config.channels, sample_rate=rate,
                              block_s=self.config.block_s, queue_s=self.config.queue_s,
                              buffer_s=self.config.buffer_s,
                              clock_ns=lambda: clock.now().nanoseconds, notify=self.wake.trigger)
        self.get_logger().info(f"ready: capturing {self.device.name!r} channels {list(self.config.channels)} at "
                               f"{rate} Hz -> {self.frames.layout.output_rate} Hz frames of {self.config.frame_s} s "
                               f"every {self.config.hop_s} s on {self.frames.pub.topic_name}")

    def on_blocks(self) -> None:
        for block in self.mic.blocks():
            if block.gap:
                self.frames.gap()
            self.frames.push(block.samples, block.stamp_ns)

    def report(self) -> None:
        counts = (self.mic.overruns, self.mic.lost_blocks, self.frames.dropped_frames)
        worse = counts != self.reported
        self.reported = counts
        status = DiagnosticStatus(
            level=DiagnosticStatus.WARN if worse else DiagnosticStatus.OK, name=f"{self.get_name()}: audio input",
            hardware_id=self.device.name,
            message="samples lost since the last report" if worse else "capturing",
            values=[KeyValue(key=k, value=str(v)) for k, v in (
                ("frames_published", self.frames.published), ("overruns", counts[0]), ("lost_blocks", counts[1]),
                ("dropped_frames", counts[2]), ("sample_rate", self.mic.sample_rate),
                ("channels", list(self.config.channels)), ("input_latency_s", f"{self.mic.latency_s:.4f}"))])
        msg = DiagnosticArray(status=[status])
        msg.header.stamp = self.get_clock().now().to_msg()
        self.pub_diagnostics.publish(msg)

    def destroy_node(self) -> None:
        if hasattr(self, "mic"):
            self.mic.close()  # first: PortAudio's thread must not wake a destroyed guard condition
            print(f"capture_node: {self.frames.published} frames published, {self.mic.overruns} overruns, "
                  f"{self.mic.lost_blocks} lost blocks, {self.frames.dropped_frames} dropped frames", flush=True)
        super().destroy_node()


def main(args=None):
    if "--list-devices" in (sys.argv if args is None else args):
        try:
            print(device_listing())
        except MicrophoneError as exc:
            print(f"capture_node: error: {exc}", file=sys.stderr)
            sys.exit(2)
        sys.exit(0)
    run_node(CaptureNode, args)


if __name__ == "__main__":
    main()
