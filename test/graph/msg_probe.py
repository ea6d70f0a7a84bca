"""Publishes (``publish``) or receives and checks (``receive OUT.json``) one sample of every m2h_msgs
type on /probe/<Type>. Run as two processes by test_messages.py."""

import json
import sys
import time
from pathlib import Path

import rclpy
from rclpy.node import Node

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from msg_values import differences, fill_rclpy, from_any, sample_values  # noqa: E402

from m2h_ros.io.msg_defs import msg_files, typestore  # noqa: E402
from m2h_ros.ros.introspection import message_class  # noqa: E402
from m2h_ros.ros.qos import STEP  # noqa: E402

TYPES = sorted(msg_files())


def topic(name: str) -> str:
    return "/probe/" + name.rsplit("/", 1)[1]


def expected_values() -> dict:
    store = typestore()
    return {name: sample_values(store, name, k) for k, name in enumerate(TYPES)}


def publish(node: Node, deadline: float) -> None:
    messages = {name: fill_rclpy(message_class(name)(), values) for name, values in expected_values().items()}
    pubs = {name: node.create_publisher(message_class(name), topic(name), STEP) for name in TYPES}
    while time.monotonic() < deadline:
        for name, pub in pubs.items():
            pub.publish(messages[name])
        rclpy.spin_once(node, timeout_sec=0.1)


def receive(node: Node, out: Path, deadline: float) -> None:
    expected = expected_values()
    report: dict[str, list[str]] = {}

    def check(name, msg):
        report.setdefault(name, differences(expected[name], from_any(msg)))

    for name in TYPES:
        node.create_subscription(message_class(name), topic(name), lambda m, n=name: check(n, m), STEP)
    while len(report) < len(TYPES) and time.monotonic() < deadline:
        rclpy.spin_once(node, timeout_sec=0.1)
    out.write_text(json.dumps(report, indent=1))


def main() -> None:
    rclpy.init()
    node = Node(f"msg_probe_{sys.argv[1]}")
    deadline = time.monotonic() + 30.0
    try:
        if sys.argv[1] == "publish":
            publish(node, deadline)
        else:
            receive(node, Path(sys.argv[2]), deadline)
    except KeyboardInterrupt:
        pass
    finally:
        node.destroy_node()
        rclpy.try_shutdown()


if __name__ == "__main__":
    main()
