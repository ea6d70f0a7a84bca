"""StepExecutor runs what rclpy's SingleThreadedExecutor runs: subscriptions, timers, parameter
services, QoS event handlers, entities created from callbacks; falls back to rclpy for the rest."""

import os
import threading
import time

import pytest

os.environ.setdefault("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")
import rclpy  # noqa: E402
from rcl_interfaces.srv import GetParameters  # noqa: E402
from rclpy.event_handler import SubscriptionEventCallbacks  # noqa: E402
from rclpy.executors import SingleThreadedExecutor  # noqa: E402
from rclpy.node import Node  # noqa: E402
from rclpy.qos import QoSProfile, ReliabilityPolicy  # noqa: E402
from std_msgs.msg import Int32  # noqa: E402

from m2h_ros.ros.executor import StepExecutor  # noqa: E402

pytestmark = pytest.mark.graph


@pytest.fixture
def context():
    ctx = rclpy.Context()
    rclpy.init(context=ctx)
    yield ctx
    ctx.try_shutdown()


@pytest.fixture
def spinning(context):
    """node_of(name) -> (a node, a StepExecutor spinning it); both destroyed after the test."""
    made = []

    def node_of(name, **node_options):
        node = Node(name, context=context, **node_options)
        executor = StepExecutor(context=context)
        executor.add_node(node)
        made.append((node, executor))
        return node, executor

    yield node_of
    for node, executor in made:
        executor.shutdown()
        node.destroy_node()


def spin_until(executor, done, timeout=10.0):
    deadline = time.monotonic() + timeout
    while not done() and time.monotonic() < deadline:
        executor.spin_once(timeout_sec=0.05)
    assert done(), "timed out"


def test_timer_publishes_and_the_subscription_created_in_a_callback_receives(spinning):
    node, executor = spinning("step_executor_pubsub")
    received, ticks = [], []
    publisher = node.create_publisher(Int32, "/step_executor_numbers", 10)

    def tick():
        ticks.append(len(ticks))
        if len(ticks) == 1:  # as the recorder does when it discovers a topic
            node.create_subscription(Int32, "/step_executor_numbers", lambda m: received.append(m.data), 10)
        publisher.publish(Int32(data=len(ticks)))

    node.create_timer(0.02, tick)
    spin_until(executor, lambda: len(received) >= 5)
    assert received == sorted(received) and len(set(received)) == len(received)
    assert executor._entities is not None, "ran rclpy's loop, not its own"


def test_a_callback_error_comes_out_of_spin_once(spinning):
    node, executor = spinning("step_executor_error")

    def fail():
        raise ValueError("from the callback")

    node.create_timer(0.01, fail)
    with pytest.raises(ValueError, match="from the callback"):
        spin_until(executor, lambda: False, timeout=2.0)


def test_incompatible_qos_reaches_the_event_handler(spinning):
    node, executor = spinning("step_executor_qos")
    events = []
    node.create_publisher(Int32, "/step_executor_qos", QoSProfile(depth=1, reliability=ReliabilityPolicy.BEST_EFFORT))
    node.create_subscription(Int32, "/step_executor_qos", lambda m: None,
                             QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE),
                             event_callbacks=SubscriptionEventCallbacks(incompatible_qos=events.append))
    spin_until(executor, lambda: events)
    assert events[0].last_policy_kind.name.endswith("RELIABILITY")


def test_parameter_services_answer(context):
    server = Node("step_executor_params", context=context, parameter_overrides=[])
    server.declare_parameter("answer", 42)
    server_executor = StepExecutor(context=context)
    server_executor.add_node(server)
    stop = threading.Event()

    def serve():
        while not stop.is_set():
            server_executor.spin_once(timeout_sec=0.05)

    thread = threading.Thread(target=serve)
    thread.start()
    try:
        client_node = Node("step_executor_param_client", context=context)
        client_executor = SingleThreadedExecutor(context=context)
        client_executor.add_node(client_node)
        client = client_node.create_client(GetParameters, "/step_executor_params/get_parameters")
        assert client.wait_for_service(timeout_sec=10.0)
        future = client.call_async(GetParameters.Request(names=["answer"]))
        client_executor.spin_until_future_complete(future, timeout_sec=10.0)
        assert future.result().values[0].integer_value == 42
    finally:
        stop.set()
        thread.join()
    client_executor.shutdown()
    server_executor.shutdown()


def test_a_node_with_a_client_falls_back_to_rclpy_and_still_runs(spinning):
    node, executor = spinning("step_executor_fallback")
    node.create_client(GetParameters, "/nobody/get_parameters")
    ticks = []
    node.create_timer(0.01, lambda: ticks.append(1))
    spin_until(executor, lambda: len(ticks) >= 3)
    assert not executor._entities.supported
