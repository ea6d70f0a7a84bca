"""The one main() of every node: init, spin, shut down cleanly on Ctrl-C / SIGTERM / errors."""

import cProfile
import os
import resource
import sys
import time
from pathlib import Path

import rclpy
from rclpy._rclpy_pybind11 import RCLError
from rclpy.executors import ExternalShutdownException
from rclpy.node import Node
from rclpy.signals import SignalHandlerOptions

from m2h_ros.allocator import keep_freed_blocks
from m2h_ros.errors import M2HError
from m2h_ros.ros import stop_signals
from m2h_ros.ros.executor import StepExecutor


class RunFinished(Exception):
    """Raised by a node's callback when its work is done: the node exits with code 0."""


def default_name(node_type: type[Node]) -> str:
    """The name a node of ``node_type`` takes unless remapped: each node lives in a module of its name
    (m2h_ros/nodes/sim_node.py holds sim_node), so a node that fails in its constructor is named too."""
    module = node_type.__module__
    if module == "__main__":  # python -m m2h_ros.nodes.<node>
        spec = getattr(sys.modules["__main__"], "__spec__", None)
        module = spec.name if spec is not None else module
    return module.rpartition(".")[2]


def run_node(node_type: type[Node], args: list[str] | None = None, *, publish_on_shutdown: bool = False) -> None:
    """Build and spin ``node_type`` until shutdown; exit code 2 on a configuration/data/pipeline error.

    ``publish_on_shutdown``: Ctrl-C and SIGTERM leave the context alive until the node is destroyed, so
    its destroy_node() can still publish (a base's last zero velocity). rclpy's own handlers shut the
    context down at the signal; without them only Python's raise KeyboardInterrupt in the spin (the node
    needs a timer, so that the executor's wait returns to Python)."""
    keep_freed_blocks()  # each step's messages are above glibc's initial mmap threshold
    node = None
    code = 0
    try:
        # SIGTERM raises KeyboardInterrupt, as SIGINT does, once: a later stop signal cannot interrupt the
        # shutdown (stop_signals says why). rclpy's own SIGTERM handling wakes the executor before it shuts
        # the context down: an executor that woke in between found the context alive and waited again,
        # with nothing left to wake it (an idle node hung in 1 of 10 SIGTERMs). rclpy's handler chains to
        # this one, and its wake-up lets Python run it.
        stop_signals.install()
        if publish_on_shutdown:
            rclpy.init(args=args, signal_handler_options=SignalHandlerOptions.NO)
        else:
            rclpy.init(args=args)  # inside the try: a Ctrl-C here is a clean exit too
        # Built before the node, so a Ctrl-C right after the node says "ready" cannot land inside
        # the executor's constructor (that leaves a half-built executor whose __del__ raises).
        executor = StepExecutor()
        with stop_signals.deferred():  # a stop is taken once the node exists: it then closes what it opened
            node = node_type()
        if not rclpy.ok():  # a Ctrl-C while the node was being built shut the context down: nothing to spin
            raise KeyboardInterrupt
        for companion in getattr(node, "companions", ()):  # nodes it runs in this process (destroys them too)
            executor.add_node(companion)
        profile_dir = os.environ.get("M2H_PROFILE_DIR")
        if profile_dir:  # cProfile of the spin (not the start-up), one <node>.prof per process
            profiler = cProfile.Profile(time.process_time)  # CPU, not wall time: idle waits cost nothing
            try:
                profiler.runcall(rclpy.spin, node, executor)
            finally:
                Path(profile_dir).mkdir(parents=True, exist_ok=True)
                profiler.dump_stats(Path(profile_dir) / f"{node.get_name()}.prof")
        else:
            rclpy.spin(node, executor)
    except (KeyboardInterrupt, ExternalShutdownException, RunFinished):
        pass
    except M2HError as exc:
        logger = node.get_logger() if node is not None else rclpy.logging.get_logger(default_name(node_type))
        logger.fatal(f"{type(exc).__name__}: {exc}")
        code = 2
    except Exception:
        # Ctrl-C / SIGTERM invalidates the context at once: a callback running then (e.g. a graph
        # query) fails with RCLError; and the KeyboardInterrupt of a stop raised inside a binding's
        # call (taking a message) comes out as pybind11's RuntimeError. Either is the shutdown that was
        # asked for, not a crash.
        if rclpy.ok() and not stop_signals.signalled():
            raise
    finally:
        stop_signals.closing()  # the run is over, however it ended: nothing may cut the closing short
        if node is not None:
            usage = resource.getrusage(resource.RUSAGE_SELF)
            total = usage.ru_utime + usage.ru_stime
            first = executor.cpu_at_first_message
            since = "" if first is None else f", {total - first:.2f} s since its first message"
            # Per-process CPU: where a graph run's time goes (scripts/bench/pipeline.py reads it).
            # Printed, not logged: after Ctrl-C the node's rosout publisher has no context left.
            print(f"{node.get_name()}: cpu time {total:.2f} s (user {usage.ru_utime:.2f}, "
                  f"system {usage.ru_stime:.2f}){since}", flush=True)
            node.destroy_node()
        try:
            rclpy.try_shutdown()
        except RCLError:  # a Ctrl-C handler shut the context down between try_shutdown's check and its call
            pass
    sys.exit(code)
