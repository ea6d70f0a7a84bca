"""Shared fixtures. Graph tests get an isolated ROS_DOMAIN_ID and localhost-only discovery, and every
process they start is stopped (SIGINT, then SIGKILL) when the test ends."""

import os
import random
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "test"))  # for the shared helpers module


def pytest_configure(config):
    # One domain per test run, so parallel runs on one machine never hear each other.
    os.environ.setdefault("ROS_DOMAIN_ID", str(random.Random(os.getpid() ^ time.time_ns()).randint(1, 100)))
    os.environ["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"


class Processes:
    """Starts processes in their own session and guarantees they are gone afterwards."""

    def __init__(self):
        self.procs: list[subprocess.Popen] = []

    def start(self, args: list[str], **kwargs) -> subprocess.Popen:
        proc = subprocess.Popen(args, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                                start_new_session=True, **kwargs)
        self.procs.append(proc)
        return proc

    @staticmethod
    def interrupt(proc: subprocess.Popen, *, timeout: float = 15.0) -> tuple[int, str, str]:
        """SIGINT, wait; returns (returncode, stdout, stderr). Kills the group if it hangs."""
        if proc.poll() is None:
            proc.send_signal(signal.SIGINT)
        try:
            out, err = proc.communicate(timeout=timeout)
        except subprocess.TimeoutExpired:
            os.killpg(proc.pid, signal.SIGKILL)
            out, err = proc.communicate()
            pytest.fail(f"{proc.args} did not exit within {timeout} s of SIGINT:\n{err}")
        return proc.returncode, out, err

    def cleanup(self) -> None:
        for proc in self.procs:
            if proc.poll() is None:
                try:
                    os.killpg(proc.pid, signal.SIGINT)
                    proc.wait(timeout=5)
                except (subprocess.TimeoutExpired, ProcessLookupError):
                    try:
                        os.killpg(proc.pid, signal.SIGKILL)
                    except ProcessLookupError:
                        pass
                    proc.wait()


@pytest.fixture
def processes():
    procs = Processes()
    yield procs
    procs.cleanup()
