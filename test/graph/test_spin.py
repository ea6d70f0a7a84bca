"""run_node: a callback that fails because Ctrl-C already invalidated the context is a clean exit;
the same failure with the context alive is a crash."""

import os

import pytest

os.environ.setdefault("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")
from rclpy.node import Node  # noqa: E402

from m2h_ros.ros.spin import run_node  # noqa: E402


class ShutDownMidCallback(Node):
    def __init__(self):
        super().__init__("shut_down_mid_callback")
        self.create_timer(0.01, self.tick)

    def tick(self):
        self.context.try_shutdown()  # what the SIGINT handler does, while this callback runs
        self.get_subscriptions_info_by_topic("/audio")  # RCLError: the context is invalid


class FailsWhileAlive(Node):
    def __init__(self):
        super().__init__("fails_while_alive")
        self.create_timer(0.01, self.tick)

    def tick(self):
        raise RuntimeError("a real bug")


def test_a_callback_cut_off_by_shutdown_exits_cleanly(capsys):
    with pytest.raises(SystemExit) as exit_info:
        run_node(ShutDownMidCallback)
    assert exit_info.value.code == 0
    assert "shut_down_mid_callback: cpu time" in capsys.readouterr().out


def test_a_callback_error_with_the_context_alive_propagates():
    with pytest.raises(RuntimeError, match="a real bug"):
        run_node(FailsWhileAlive)
