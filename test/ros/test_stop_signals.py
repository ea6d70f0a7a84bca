"""The nodes' stop handling without ROS: one stop per process, and none inside a node's constructor."""

from __future__ import annotations

import os
import subprocess
import sys

SCRIPT = """
import os, signal
from m2h_ros.ros import stop_signals
stop_signals.install()
built = False
try:
    with stop_signals.deferred():
        os.kill(os.getpid(), signal.SIGTERM)   # lands while the node is being built
        built = True
    print("not stopped")
except KeyboardInterrupt:
    print("stopped after building" if built else "stopped inside the constructor")
os.kill(os.getpid(), signal.SIGINT)            # a second stop is ignored
print("still closing")
"""


def test_a_stop_inside_a_constructor_is_raised_once_the_node_is_built_and_a_second_is_ignored():
    result = subprocess.run([sys.executable, "-c", SCRIPT], capture_output=True, text=True, timeout=60,
                            env={**os.environ, "PYTHONPATH": os.pathsep.join(sys.path)})
    assert result.returncode == 0, result.stderr
    assert result.stdout.split("\n")[:2] == ["stopped after building", "still closing"], result.stdout


def test_a_stop_outside_deferred_is_raised_at_once():
    script = ("import os, signal\nfrom m2h_ros.ros import stop_signals\nstop_signals.install()\n"
              "try:\n    os.kill(os.getpid(), signal.SIGTERM)\n    import time; time.sleep(5)\n    print('late')\n"
              "except KeyboardInterrupt:\n    print('stopped')\n")
    result = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=60)
    assert (result.returncode, result.stdout.strip()) == (0, "stopped"), result.stdout + result.stderr
