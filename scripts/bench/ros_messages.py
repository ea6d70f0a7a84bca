#!/usr/bin/env python3
"""CPU a subscriber process spends per received message: rclpy's SingleThreadedExecutor vs the nodes'
StepExecutor, glibc's default allocator vs ``allocator.keep_freed_blocks``, small vs step-sized
messages, a node with one subscription vs one with 13 (like the recorder). Two processes on this
machine, localhost discovery, ``BinauralAudio`` messages at 100 Hz.

    python scripts/bench/ros_messages.py [--messages 300] [--repeats 2]
"""

from __future__ import annotations

import argparse
import array
import json
import os
import random
import resource
import subprocess
import sys
import time

from m2h_ros.machine import load_average

CASES = (  # (label, executor, keep freed blocks, floats per message, extra subscriptions)
    ("rclpy executor, 1 KiB, 1 subscription", "rclpy", True, 256, 0),
    ("StepExecutor, 1 KiB, 1 subscription", "step", True, 256, 0),
    ("rclpy executor, 1 KiB, 13 subscriptions", "rclpy", True, 256, 12),
    ("StepExecutor, 1 KiB, 13 subscriptions", "step", True, 256, 12),
    ("StepExecutor, 188 KiB, glibc defaults", "step", False, 48000, 0),
    ("StepExecutor, 188 KiB, keep_freed_blocks", "step", True, 48000, 0),
)


def cpu_seconds() -> float:
    usage = resource.getrusage(resource.RUSAGE_SELF)
    return usage.ru_utime + usage.ru_stime


def child(role: str, executor: str, keep: bool, floats: int, extra: int, count: int) -> None:
    if keep:
        from m2h_ros.allocator import keep_freed_blocks

        keep_freed_blocks()
    import rclpy
    from m2h_msgs.msg import BinauralAudio
    from rclpy.executors import SingleThreadedExecutor

    from m2h_ros.ros.executor import StepExecutor
    from m2h_ros.ros.qos import STEP, subscription_events

    rclpy.init()
    node = rclpy.create_node(f"bench_{role}")
    if role == "pub":
        publisher = node.create_publisher(BinauralAudio, "/bench_messages", STEP)
        while publisher.get_subscription_count() == 0:
            rclpy.spin_once(node, timeout_sec=0.05)
        time.sleep(1.0)
        samples = array.array("f", bytes(4 * floats))
        for step in range(count):
            publisher.publish(BinauralAudio(step=step, samples=samples))
            time.sleep(0.01)
        time.sleep(1.0)
        return
    received = [0, 0.0]

    def on_message(msg) -> None:
        if received[0] == 0:
            received[1] = cpu_seconds()
        received[0] += 1

    node.create_subscription(BinauralAudio, "/bench_messages", on_message, STEP,
                             event_callbacks=subscription_events(node.get_logger(), "/bench_messages"))
    for index in range(extra):  # endpoints that stay idle, as the recorder's other topics between steps
        topic = f"/bench_idle_{index}"
        node.create_subscription(BinauralAudio, topic, lambda m: None, STEP,
                                 event_callbacks=subscription_events(node.get_logger(), topic))
    spinner = StepExecutor() if executor == "step" else SingleThreadedExecutor()
    spinner.add_node(node)
    deadline = time.monotonic() + 60
    while received[0] < count and time.monotonic() < deadline:
        spinner.spin_once(timeout_sec=0.1)
    per_message = (cpu_seconds() - received[1]) / max(received[0] - 1, 1) * 1e3
    print(json.dumps({"received": received[0], "ms_per_message": per_message}))


def measure(case: tuple, count: int, env: dict) -> float:
    _, executor, keep, floats, extra = case
    settings = [executor, str(int(keep)), str(floats), str(extra), str(count)]
    sub = subprocess.Popen([sys.executable, __file__, "--child", "sub", *settings], stdout=subprocess.PIPE, text=True,
                           env=env)
    time.sleep(1.0)
    subprocess.run([sys.executable, __file__, "--child", "pub", *settings], check=True, env=env)
    out, _ = sub.communicate(timeout=120)
    result = json.loads(out.strip().splitlines()[-1])
    if result["received"] < count:
        raise SystemExit(f"{case[0]}: only {result['received']} of {count} messages arrived")
    return result["ms_per_message"]


def main(argv=None) -> int:
    if len(sys.argv) > 2 and sys.argv[1] == "--child":
        role, executor, keep, floats, extra, count = sys.argv[2:8]
        child(role, executor, keep == "1", int(floats), int(extra), int(count))
        return 0
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--messages", type=int, default=300)
    parser.add_argument("--repeats", type=int, default=2)
    args = parser.parse_args(argv)
    env = {**os.environ, "ROS_AUTOMATIC_DISCOVERY_RANGE": "LOCALHOST",
           "ROS_DOMAIN_ID": os.environ.get("ROS_DOMAIN_ID", str(random.randint(1, 100)))}
    print(f"load average before: {load_average()}")
    for case in CASES:
        values = [measure(case, args.messages, env) for _ in range(args.repeats)]
        print(f"{case[0]:45s} subscriber CPU per message: " + " / ".join(f"{v:.3f}" for v in values) + " ms",
              flush=True)
    print(f"load average after: {load_average()}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
