"""The console scripts of the nodes (``ros2 run m2h_ros <node>``).

Each imports its node module only when called, so a Ctrl-C or SIGTERM while the node is still
importing (seconds: torch is among its modules) ends it as quietly as one a moment later does: exit
code 0, no traceback. The installed scripts import these entry points directly (setup.py), so the only moment
left in which a Ctrl-C prints a traceback is Python's own start-up before the script runs (its site
packages' .pth files: some 10 to 20 ms). Once the node has exited (run_node: its bag closed, its
tables written) the process ends at once: Python's own finalisation after an rclpy shutdown could hang
in native code for seconds (under ros2 launch every node was still alive 5 s after its SIGINT, until
launch's SIGTERM)."""

import importlib
import os
import signal
import sys

from m2h_ros.ros import stop_signals

NODES = ("sim_node", "separator_node", "controller_node", "evaluator_node", "recorder_node", "live_view_node",
         "capture_node", "base_node", "episode_driver", "audio_common_adapter")


def run(node: str) -> None:
    stop_signals.install()  # the first SIGINT or SIGTERM stops the node, a later one cannot interrupt that
    stops = set(stop_signals.STOP_SIGNALS)
    try:
        parent = os.environ.pop(stop_signals.PARENT_ENV, "")  # popped: not for processes the node starts
        if parent.isdigit() and int(parent) in (os.getppid(), 1):  # 1: the launch died before this line
            stop_signals.stop_with(int(parent))()  # none outlives its launch (a dead one's SIGTERM: exit 0)
        # Held while importing: one that lands inside an extension module's initialisation (torch's) came
        # out as ImportError or was lost, and the node started anyway. Released here, it stops the node.
        signal.pthread_sigmask(signal.SIG_BLOCK, stops)
        try:
            module = importlib.import_module(f"m2h_ros.nodes.{node}")
        finally:
            signal.pthread_sigmask(signal.SIG_UNBLOCK, stops)
    except KeyboardInterrupt:
        sys.exit(0)
    try:
        module.main()
    except KeyboardInterrupt:  # a stop before the node's own main() could take it: nothing was opened yet
        os._exit(0)
    except SystemExit as exc:
        sys.stdout.flush()
        sys.stderr.flush()
        os._exit(exc.code if isinstance(exc.code, int) else 0 if exc.code is None else 1)


def __getattr__(name: str):
    """``m2h_ros.nodes.entry:<node>``, the entry point setup.py declares for each node."""
    if name in NODES:
        return lambda: run(name)
    raise AttributeError(name)
