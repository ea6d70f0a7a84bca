"""Message classes by type name, and the QoS a subscriber should use to hear every publisher."""

import importlib

from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy

from m2h_ros.ros.qos import RECORD


def message_class(type_name: str) -> type:
    """``pkg/msg/Name`` -> the generated Python class."""
    package, kind, name = type_name.split("/")
    return getattr(importlib.import_module(f"{package}.{kind}"), name)


def adapted_qos(node: Node, topic: str) -> QoSProfile:
    """Like rosbag2: reliable / transient-local only when every current publisher offers it."""
    infos = node.get_publishers_info_by_topic(topic)
    qos = QoSProfile(history=RECORD.history, depth=RECORD.depth,
                     reliability=RECORD.reliability, durability=RECORD.durability)
    if infos and all(i.qos_profile.reliability == ReliabilityPolicy.RELIABLE for i in infos):
        qos.reliability = ReliabilityPolicy.RELIABLE
    if infos and all(i.qos_profile.durability == DurabilityPolicy.TRANSIENT_LOCAL for i in infos):
        qos.durability = DurabilityPolicy.TRANSIENT_LOCAL
    return qos
