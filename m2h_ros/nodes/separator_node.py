"""separator_node: the separator: turns each step's binaural audio into the target's separated spectrograms (f^B, f^M, f^R).

Its step logic lands with the pipeline issue; today it declares and validates its parameters."""

from rclpy.node import Node

from m2h_ros.node_configs import SeparatorNodeConfig
from m2h_ros.ros.params import declare_config
from m2h_ros.ros.spin import run_node


class SeparatorNode(Node):
    def __init__(self):
        super().__init__("separator_node")
        self.config: SeparatorNodeConfig = declare_config(self, SeparatorNodeConfig)
        self.get_logger().info(f"ready: {self.config}")


def main(args=None):
    run_node(SeparatorNode, args)


if __name__ == "__main__":
    main()
