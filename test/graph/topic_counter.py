"""Subscribes to one sensor_msgs/Image topic (argv[1]), says "subscribed", and at Ctrl-C prints how many
messages it received: the one viewer of a run (run as a script by test_derived_topics.py)."""

import sys

import rclpy
from rclpy.node import Node
from sensor_msgs.msg import Image
from stand_in import spin_until_stopped

from m2h_ros.ros.qos import STEP


class TopicCounter(Node):
    def __init__(self, topic: str):
        super().__init__("topic_counter")
        self.received = 0
        self.create_subscription(Image, topic, self.count, STEP)
        print("subscribed", flush=True)

    def count(self, _msg: Image) -> None:
        self.received += 1

    def destroy_node(self) -> None:
        print(f"received {self.received}", flush=True)
        super().destroy_node()


if __name__ == "__main__":
    rclpy.init()
    spin_until_stopped(TopicCounter(sys.argv[1]))
