"""A test-only stand-in for ros-drivers' audio_capture_node run by its capture_wave launch file: in the
namespace audio it publishes audio_common_msgs/AudioDataStamped on audio/audio_stamped and AudioData on
audio/audio (20 ms blocks of S16LE, --channels channels at --rate, paced in real time and stamped at
capture), and AudioInfo on audio/audio_info at start and every 5 s, as the driver does. The signal:
a 220 Hz tone on the first channel, 330 Hz on the second, with noise."""

import argparse
import time

import numpy as np
import rclpy
from audio_common_msgs.msg import AudioData, AudioDataStamped, AudioInfo

from m2h_ros.ros import convert
from stand_in import spin_until_stopped

BLOCK_S = 0.02
INFO_EVERY_S = 5.0


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--rate", type=int, default=48000)
    parser.add_argument("--channels", type=int, default=2)
    args = parser.parse_args()
    block = round(args.rate * BLOCK_S)
    rng = np.random.default_rng(5)
    t = np.arange(args.rate * 10) / args.rate  # 10 s, looped
    tones = [np.sin(2 * np.pi * f * t) for f in (220.0, 330.0)] + [np.zeros_like(t)] * max(0, args.channels - 2)
    pcm = ((np.stack(tones[:args.channels], axis=1) * 0.2 + 0.05 * rng.standard_normal((t.size, args.channels)))
           * 32767).clip(-32768, 32767).astype("<i2")
    rclpy.init()
    node = rclpy.create_node("audio_capture", namespace="audio")
    pub_audio = node.create_publisher(AudioData, "audio", 10)
    pub_stamped = node.create_publisher(AudioDataStamped, "audio_stamped", 10)
    pub_info = node.create_publisher(AudioInfo, "audio_info", 1)
    info = AudioInfo(channels=args.channels, sample_rate=args.rate, sample_format="S16LE",
                     bitrate=args.rate * 16 * args.channels, coding_format="wave")
    start_ns, sent = time.time_ns(), 0

    def publish_due_blocks() -> None:
        nonlocal sent
        due = (time.time_ns() - start_ns) * args.rate // 10**9 // block  # blocks whose capture has ended
        while sent < due:
            first = sent * block % (len(pcm) - block)
            data = AudioData(data=pcm[first:first + block].tobytes())
            stamped = AudioDataStamped(audio=data)
            stamped.header.stamp = convert.stamp_of(start_ns + sent * block * 10**9 // args.rate)
            pub_audio.publish(data)
            pub_stamped.publish(stamped)
            sent += 1

    pub_info.publish(info)
    node.create_timer(INFO_EVERY_S, lambda: pub_info.publish(info))
    node.create_timer(BLOCK_S / 2, publish_due_blocks)
    spin_until_stopped(node)


if __name__ == "__main__":
    main()
