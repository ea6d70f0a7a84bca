"""A test-only robot base: integrates the twist it is sent on cmd_vel (m2h_ros.core.robot.base_motion.
KinematicBase: applied --latency late, odometry with Gaussian noise, an optional wall at x = --wall-x)
and publishes nav_msgs/Odometry on odom at --odom-hz. --odom-stops-after S: odometry stops S seconds
after the first non-zero twist (stale odometry).

    python test/graph/kinematic_base.py [--twist] [--latency 0.05] [--wall-x 0.4] [--odom-stops-after 0.5]
"""

import argparse
import sys
import time

import numpy as np
import rclpy
from rclpy.utilities import remove_ros_args
from geometry_msgs.msg import Twist, TwistStamped
from nav_msgs.msg import Odometry

from m2h_ros import topics
from m2h_ros.core.robot.base_motion import KinematicBase
from m2h_ros.ros import convert
from stand_in import spin_until_stopped

TICK_S = 0.005


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--twist", action="store_true", help="plain Twist on cmd_vel (default TwistStamped)")
    parser.add_argument("--latency", type=float, default=0.05)
    parser.add_argument("--noise-m", type=float, default=0.005)
    parser.add_argument("--noise-rad", type=float, default=0.005)
    parser.add_argument("--wall-x", type=float, default=float("inf"))
    parser.add_argument("--odom-hz", type=float, default=20.0)
    parser.add_argument("--odom-stops-after", type=float, default=None)
    args = parser.parse_args(remove_ros_args(sys.argv)[1:])  # --ros-args -r ...: a driver's own topic names
    rclpy.init(args=sys.argv)
    node = rclpy.create_node("kinematic_base")
    base = KinematicBase(latency_s=args.latency, noise_m=args.noise_m, noise_rad=args.noise_rad, wall_x=args.wall_x)
    state = {"moving_since": None, "last": time.monotonic(), "next_odom": 0.0}
    pub = node.create_publisher(Odometry, topics.ODOM, 10)

    def on_twist(msg) -> None:
        twist = msg if args.twist else msg.twist
        velocity = (twist.linear.x, twist.angular.z)
        if velocity != (0.0, 0.0) and state["moving_since"] is None:
            state["moving_since"] = time.monotonic()
        base.command(velocity, time.monotonic())

    def tick() -> None:
        now = time.monotonic()
        base.advance(now, now - state["last"])
        state["last"] = now
        stopped = (args.odom_stops_after is not None and state["moving_since"] is not None
                   and now - state["moving_since"] > args.odom_stops_after)
        if now >= state["next_odom"] and not stopped:
            state["next_odom"] = now + 1.0 / args.odom_hz
            pose = base.odometry()
            pub.publish(convert.odometry_msg(np.array([pose.x, pose.y, pose.yaw]),
                                             stamp_ns=node.get_clock().now().nanoseconds))

    node.create_subscription(Twist if args.twist else TwistStamped, topics.CMD_VEL, on_twist, 10)
    node.create_timer(TICK_S, tick)
    node.get_logger().info("ready")
    spin_until_stopped(node)


if __name__ == "__main__":
    main()
