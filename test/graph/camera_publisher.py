"""A test-only robot camera: publishes a fixed RGB image (rgb8) and depth image (32FC1, metres) of
--size pixels on camera/rgb/image_raw and camera/depth/image_raw at --hz."""

import argparse

import numpy as np
import rclpy
from rclpy.executors import ExternalShutdownException
from sensor_msgs.msg import Image

from m2h_ros import topics
from m2h_ros.ros import convert


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--size", type=int, default=128)
    parser.add_argument("--hz", type=float, default=10.0)
    args = parser.parse_args()
    rng = np.random.default_rng(0)
    rgb = rng.integers(0, 256, (args.size, args.size, 3), dtype=np.uint8)
    depth = rng.uniform(0.5, 5.0, (args.size, args.size)).astype(np.float32)
    rclpy.init()
    node = rclpy.create_node("test_camera")
    pub_rgb, pub_depth = node.create_publisher(Image, topics.RGB, 10), node.create_publisher(Image, topics.DEPTH, 10)

    def publish() -> None:
        stamp = node.get_clock().now().nanoseconds
        pub_rgb.publish(convert.rgb_msg(rgb, stamp_ns=stamp))
        pub_depth.publish(convert.depth_msg(depth, stamp_ns=stamp))

    node.create_timer(1.0 / args.hz, publish)
    try:
        rclpy.spin(node)
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    finally:
        node.destroy_node()
        rclpy.try_shutdown()


if __name__ == "__main__":
    main()
