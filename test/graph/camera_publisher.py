"""A test-only robot camera: publishes a fixed RGB image (rgb8) and depth image (32FC1, metres) of
--width x --height pixels on camera/rgb/image_raw and camera/depth/image_raw at --hz. --driver publishes
them as RealSense's driver does instead: bgr8 colour and 16UC1 depth in millimetres, 0 where no reading."""

import argparse
import sys
import array

import numpy as np
import rclpy
from rclpy.utilities import remove_ros_args
from sensor_msgs.msg import Image

from m2h_ros import topics
from m2h_ros.ros import convert
from stand_in import spin_until_stopped


def driver_image(values: np.ndarray, encoding: str, stamp_ns: int) -> Image:
    height, width = values.shape[:2]
    data = np.ascontiguousarray(values).tobytes()
    msg = Image(height=height, width=width, encoding=encoding, is_bigendian=0, step=len(data) // height)
    msg.header.stamp, msg.header.frame_id = convert.stamp_of(stamp_ns), "camera_color_optical_frame"
    msg.data = array.array("B", data)
    return msg


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--width", type=int, default=128)
    parser.add_argument("--height", type=int, default=128)
    parser.add_argument("--hz", type=float, default=10.0)
    parser.add_argument("--driver", action="store_true", help="bgr8 and 16UC1 millimetres")
    args = parser.parse_args(remove_ros_args(sys.argv)[1:])  # --ros-args -r ...: a driver's own topic names
    rng = np.random.default_rng(0)
    rgb = rng.integers(0, 256, (args.height, args.width, 3), dtype=np.uint8)
    depth = rng.uniform(0.5, 5.0, (args.height, args.width)).astype(np.float32)
    depth[::7, ::5] = 0.0  # no reading
    rclpy.init(args=sys.argv)
    node = rclpy.create_node("test_camera")
    pub_rgb, pub_depth = node.create_publisher(Image, topics.RGB, 10), node.create_publisher(Image, topics.DEPTH, 10)

    def publish() -> None:
        stamp = node.get_clock().now().nanoseconds
        if args.driver:
            pub_rgb.publish(driver_image(rgb[..., ::-1], "bgr8", stamp))
            pub_depth.publish(driver_image(np.rint(depth * 1000).astype("<u2"), "16UC1", stamp))
        else:
            pub_rgb.publish(convert.rgb_msg(rgb, stamp_ns=stamp))
            pub_depth.publish(convert.depth_msg(depth, stamp_ns=stamp))

    node.create_timer(1.0 / args.hz, publish)
    spin_until_stopped(node)


if __name__ == "__main__":
    main()
