"""sim_node: the simulator: publishes each step's binaural audio, camera frame, pose and episode info, applies motion commands.

Its step logic lands with the pipeline issue; today it declares and validates its parameters."""

from rclpy.node import Node

from m2h_ros.node_configs import SimConfig
from m2h_ros.ros.params import declare_config
from m2h_ros.ros.spin import run_node


class SimNode(Node):
    def __init__(self):
        super().__init__("sim_node")
        self.config: SimConfig = declare_config(self, SimConfig)
        self.get_logger().info(f"ready: {self.config}")


def main(args=None):
    run_node(SimNode, args)


if __name__ == "__main__":
    main()
