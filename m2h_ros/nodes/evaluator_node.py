"""evaluator_node: the evaluator: scores each step's estimate against the ground truth (SI-SDR, STFT distance, SR, SPL).

Its step logic lands with the pipeline issue; today it declares and validates its parameters."""

from rclpy.node import Node

from m2h_ros.node_configs import EvaluatorConfig
from m2h_ros.ros.params import declare_config
from m2h_ros.ros.spin import run_node


class EvaluatorNode(Node):
    def __init__(self):
        super().__init__("evaluator_node")
        self.config: EvaluatorConfig = declare_config(self, EvaluatorConfig)
        self.get_logger().info(f"ready: {self.config}")


def main(args=None):
    run_node(EvaluatorNode, args)


if __name__ == "__main__":
    main()
