"""What the test-only stand-ins for a robot's drivers share (run as scripts from this folder)."""

import rclpy
from rclpy.executors import ExternalShutdownException
from rclpy.node import Node


def spin_until_stopped(node: Node) -> None:
    """Spin ``node`` until Ctrl-C, SIGTERM or shutdown, then tear it and rclpy down quietly."""
    try:
        rclpy.spin(node)
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    finally:
        node.destroy_node()
        rclpy.try_shutdown()
