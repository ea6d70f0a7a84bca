"""base_node against the test-only kinematic base (latency, odometry noise): each command carried out
closed-loop and reported (done, blocked by a wall, aborted on stale odometry), zero velocity at every
end and on shutdown, TwistStamped or plain Twist."""

import math
import signal
import sys
import threading
import time
from pathlib import Path

import pytest
import rclpy
from geometry_msgs.msg import Twist, TwistStamped
from m2h_msgs.msg import MotionCommand, MotionResult
from nav_msgs.msg import Odometry
from pipeline_helpers import node_args
from rclpy.executors import SingleThreadedExecutor

from m2h_ros import topics
from m2h_ros.ros.qos import STEP

pytestmark = pytest.mark.graph
KINEMATIC_BASE = str(Path(__file__).with_name("kinematic_base.py"))
FORWARD, LEFT, RIGHT, STOP = (MotionCommand.MOVE_FORWARD, MotionCommand.TURN_LEFT, MotionCommand.TURN_RIGHT,
                              MotionCommand.STOP)


class Driver:
    """The test's side of the graph: sends MotionCommands, hears MotionResults and cmd_vel."""

    def __init__(self, *, stamped: bool = True):
        self.context = rclpy.Context()
        self.context.init()
        self.node = rclpy.create_node("base_test_driver", context=self.context)
        self.results: list[MotionResult] = []
        self.twists: list[tuple[float, float]] = []
        self.pub = self.node.create_publisher(MotionCommand, topics.COMMAND, STEP)
        self.node.create_subscription(MotionResult, topics.MOTION_RESULT, self.results.append, STEP)

        def on_twist(msg):
            twist = msg.twist if stamped else msg
            self.twists.append((twist.linear.x, twist.angular.z))

        self.node.create_subscription(TwistStamped if stamped else Twist, topics.CMD_VEL, on_twist, 10)
        self.odometry = 0
        self.node.create_subscription(Odometry, topics.ODOM, lambda _: setattr(self, "odometry", self.odometry + 1), 10)
        self.executor = SingleThreadedExecutor(context=self.context)
        self.executor.add_node(self.node)
        self.thread = threading.Thread(target=self.executor.spin, daemon=True)
        self.thread.start()

    def wait_for(self, condition, timeout: float, what: str):
        deadline = time.monotonic() + timeout
        while not condition():
            if time.monotonic() > deadline:
                pytest.fail(f"no {what} within {timeout} s; results {self.results}, last twists {self.twists[-3:]}")
            time.sleep(0.02)

    def ready(self, timeout: float = 60.0) -> None:
        """base_node subscribes to the commands and this test's base publishes odometry (a base of an
        earlier test may linger in discovery: only its messages count)."""
        self.wait_for(lambda: self.pub.get_subscription_count() > 0 and self.odometry > 0, timeout,
                      "base_node / odometry")
        time.sleep(0.5)  # odometry flowing into base_node

    def move(self, action: int, step: int, timeout: float = 30.0) -> MotionResult:
        count = len(self.results)
        self.pub.publish(MotionCommand(episode_id="robot", step=step, action=action, controller="test"))
        self.wait_for(lambda: len(self.results) > count, timeout, f"result for step {step}")
        result = self.results[count]
        assert (result.episode_id, result.step, result.action) == ("robot", step, action)
        time.sleep(0.2)  # the zero twist sent with the result arrives
        return result

    def close(self) -> None:
        self.executor.shutdown()
        self.node.destroy_node()
        self.context.try_shutdown()


@pytest.fixture
def graph(processes):
    """Start the kinematic base (its arguments) and base_node (its parameters); yield the driver."""
    drivers = []

    def start(*base_args: str, stamped: bool = True, **params):
        base = processes.start([sys.executable, KINEMATIC_BASE, *base_args, *([] if stamped else ["--twist"])])
        node = processes.start(node_args("base_node", twist_stamped=stamped, **params))
        drivers.append(Driver(stamped=stamped))
        drivers[-1].ready()
        return drivers[-1], base, node

    yield start
    for driver in drivers:
        driver.close()


def test_steps_and_turns_are_carried_out_closed_loop_and_reported(graph):
    driver, _, _ = graph()
    for step, action in enumerate((FORWARD, LEFT, FORWARD, RIGHT, STOP)):
        result = driver.move(action, step)
        assert result.status == MotionResult.DONE, result.reason
        assert driver.twists[-1] == (0.0, 0.0)  # stopped at the end
        if action == FORWARD:
            assert abs(result.position_error) < 0.03 and abs(result.heading_error) < 0.03, result
            assert max(v for v, _ in driver.twists) <= 0.3 + 1e-9  # the speed limit
        elif action in (LEFT, RIGHT):
            assert abs(result.heading_error) < 0.03, result
    assert driver.results[-1].duration == 0.0  # STOP: no motion


def test_a_wall_blocks_the_move_and_the_base_stops(graph):
    driver, _, _ = graph("--wall-x", "0.4", blocked_timeout_s=1.5)
    result = driver.move(FORWARD, 0)
    assert result.status == MotionResult.BLOCKED, result.reason
    assert "no progress" in result.reason
    assert 0.55 < result.position_error < 0.7  # stopped at the wall, 1 m - 0.4 m short
    assert driver.twists[-1] == (0.0, 0.0)


def test_stale_odometry_aborts_the_move_and_stops_the_base(graph):
    driver, _, _ = graph("--odom-stops-after", "0.5")
    result = driver.move(FORWARD, 0)
    assert result.status == MotionResult.ABORTED and "odometry stale" in result.reason
    assert result.duration < 2.0
    assert driver.twists[-1] == (0.0, 0.0)
    later = driver.move(LEFT, 1)  # no odometry: nothing moves
    assert later.status == MotionResult.ABORTED and "no odometry on /odom within" in later.reason  # as remapped


@pytest.mark.parametrize("presses", [1, 5], ids=["ctrl-c", "ctrl-c-repeated"])
def test_shutdown_mid_move_sends_zero_velocity_on_plain_twist(presses, graph, processes):
    """Also with Ctrl-C pressed again while the node waits for its zero velocity to be acknowledged."""
    driver, _, node = graph(stamped=False)
    driver.pub.publish(MotionCommand(episode_id="robot", step=0, action=FORWARD, controller="test"))
    driver.wait_for(lambda: any(v > 0.1 for v, _ in driver.twists), 30, "motion")
    for _ in range(presses - 1):
        node.send_signal(signal.SIGINT)
        time.sleep(0.03)
    code, _, err = processes.interrupt(node)
    assert code == 0 and "Traceback" not in err, err
    driver.wait_for(lambda: driver.twists[-1] == (0.0, 0.0), 5, "zero velocity after SIGINT")
    assert not math.isnan(driver.twists[-1][0])


def test_a_command_before_any_odometry_waits_for_it(processes):
    """The base driver's odometry can reach base_node seconds after its first command (discovery at
    start-up): the command waits for it and is carried out."""
    node = processes.start(node_args("base_node"))
    driver = Driver()
    try:
        driver.wait_for(lambda: driver.pub.get_subscription_count() > 0, 60, "base_node")
        time.sleep(0.5)
        driver.pub.publish(MotionCommand(episode_id="robot", step=0, action=LEFT, controller="test"))
        time.sleep(2.0)  # longer than odom_timeout_s: no odometry yet, and no result either
        assert driver.results == []
        processes.start([sys.executable, KINEMATIC_BASE])
        driver.wait_for(lambda: driver.results, 60, "result for step 0")
        assert driver.results[0].status == MotionResult.DONE, driver.results[0].reason
    finally:
        driver.close()
        processes.interrupt(node)
