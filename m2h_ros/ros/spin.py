"""The one main() of every node: init, spin, shut down cleanly on Ctrl-C / SIGTERM / errors."""

import sys

import rclpy
from rclpy.executors import ExternalShutdownException
from rclpy.node import Node

from m2h_ros.errors import M2HError


class RunFinished(Exception):
    """Raised by a node's callback when its work is done: the node exits with code 0."""


def run_node(node_type: type[Node], args: list[str] | None = None) -> None:
    """Build and spin ``node_type`` until shutdown; exit code 2 on a configuration/data/pipeline error."""
    rclpy.init(args=args)
    node = None
    code = 0
    try:
        node = node_type()
        rclpy.spin(node)
    except (KeyboardInterrupt, ExternalShutdownException, RunFinished):
        pass
    except M2HError as exc:
        rclpy.logging.get_logger(node_type.__name__).fatal(f"{type(exc).__name__}: {exc}")
        code = 2
    finally:
        if node is not None:
            node.destroy_node()
        rclpy.try_shutdown()
    sys.exit(code)
