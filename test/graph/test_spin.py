"""run_node: a callback that fails because Ctrl-C already invalidated the context is a clean exit, as is
one whose call a stop interrupted inside a binding; the same failure with the context alive and no stop
is a crash."""

import os

import pytest

os.environ.setdefault("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")
from rclpy.node import Node  # noqa: E402

from m2h_ros.ros import stop_signals  # noqa: E402
from m2h_ros.ros.spin import run_node  # noqa: E402


class ShutDownMidCallback(Node):
    def __init__(self):
        super().__init__("shut_down_mid_callback")
        self.create_timer(0.01, self.tick)

    def tick(self):
        self.context.try_shutdown()  # what the SIGINT handler does, while this callback runs
        self.get_subscriptions_info_by_topic("/audio")  # RCLError: the context is invalid


class StoppedInsideABinding(Node):
    def __init__(self):
        super().__init__("stopped_inside_a_binding")
        self.create_timer(0.01, self.tick)

    def tick(self):
        try:
            stop_signals.stop_once(None, None)  # Ctrl-C's handler, run while a binding converts a message
        except KeyboardInterrupt:
            # pybind11 turns an exception raised inside its argument conversion into this one
            raise RuntimeError("Unable to convert call argument '0' to Python object") from None


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


def test_a_stop_that_surfaces_as_another_error_inside_a_binding_exits_cleanly(monkeypatch, capsys):
    monkeypatch.setattr(stop_signals, "_stopping", False)  # the stop is this test's alone: no other
    monkeypatch.setattr(stop_signals, "_signalled", False)  # run_node in this process sees it
    with pytest.raises(SystemExit) as exit_info:
        run_node(StoppedInsideABinding)
    assert exit_info.value.code == 0
    assert "stopped_inside_a_binding: cpu time" in capsys.readouterr().out
