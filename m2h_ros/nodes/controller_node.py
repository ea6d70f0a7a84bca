"""controller_node: the controller: chooses each step's motion command (Move2Hear or a baseline).

Its step logic lands with the pipeline issue; today it declares and validates its parameters."""

from rclpy.node import Node

from m2h_ros.node_configs import ControllerConfig
from m2h_ros.ros.params import declare_config
from m2h_ros.ros.spin import run_node


class ControllerNode(Node):
    def __init__(self):
        super().__init__("controller_node")
        self.config: ControllerConfig = declare_config(self, ControllerConfig)
        self.get_logger().info(f"ready: {self.config}")


def main(args=None):
    run_node(ControllerNode, args)


if __name__ == "__main__":
    main()
