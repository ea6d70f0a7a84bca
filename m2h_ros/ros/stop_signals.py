"""One stop per process: the first SIGINT or SIGTERM stops it, every later one is ignored.

A terminal's Ctrl-C goes to the whole process group, so under ``ros2 launch`` each node gets SIGINT
twice (from the terminal and from launch forwarding it), and a held Ctrl-C sends it again and again. A
second KeyboardInterrupt landing in a node's shutdown interrupted it: no bag footer, no tables, no last
zero velocity, exit code -2. Once a stop has begun (or the node's work is done and it is closing), the
process finishes closing its outputs; ``ros2 launch``'s SIGTERM 5 s later is ignored as well, and only its
SIGKILL 5 s after that could cut the shutdown short.

ROS-free and cheap to import: the nodes' entry points install the handler before importing anything.
"""

import ctypes
import os
import signal
from collections.abc import Callable, Iterator
from contextlib import contextmanager

STOP_SIGNALS = (signal.SIGINT, signal.SIGTERM)
# Set by the launch files to the launch process's id: a node it starts stops when that process dies.
PARENT_ENV = "M2H_STOP_WITH_PARENT"
PR_SET_PDEATHSIG = 1  # linux/prctl.h
_stopping = False
_signalled = False  # a stop signal came (not merely closing)
_deferring = False  # inside deferred(): a stop is noted, not raised
_pending = False    # a stop came while deferring


def stop_once(signum, frame) -> None:
    """The handler of SIGINT and SIGTERM: KeyboardInterrupt the first time, nothing afterwards."""
    global _stopping, _pending, _signalled
    _signalled = True
    if _deferring:
        _pending = True
    elif not _stopping:
        _stopping = True
        raise KeyboardInterrupt


@contextmanager
def deferred() -> Iterator[None]:
    """A stop signal that comes while the block runs is raised (KeyboardInterrupt) when it ends: a node's
    constructor interrupted after it opened an output (the recorder's bag) left no node to close it."""
    global _deferring, _pending
    _deferring = True
    try:
        yield
    finally:
        _deferring = False
    if _pending:
        _pending = False
        stop_once(None, None)


def install() -> None:
    """:func:`stop_once` for SIGINT and SIGTERM (SIGTERM stops as Ctrl-C does). Also where SIGINT was
    inherited ignored (a background job of a non-interactive shell): a node must still stop on it."""
    for signum in STOP_SIGNALS:
        signal.signal(signum, stop_once)


def signalled() -> bool:
    """Whether a stop signal has come. A KeyboardInterrupt raised while a binding converts a message can
    surface as another exception (pybind11's RuntimeError "Unable to convert call argument"): with this
    true, that exception is the stop, not a crash."""
    return _signalled


def closing() -> None:
    """The process is closing its outputs: a stop signal from now on is ignored."""
    global _stopping
    _stopping = True


def ignore() -> None:
    """SIGINT and SIGTERM ignored from now on, for a process about to end that has no rclpy context:
    Python's finalisation puts back the default handlers, and a late Ctrl-C would kill it (exit -2)."""
    for signum in STOP_SIGNALS:
        signal.signal(signum, signal.SIG_IGN)


def stop_with(parent: int) -> Callable[[], None]:
    """What makes a process get SIGTERM (and so stop as on Ctrl-C) when ``parent`` dies, however it dies
    (SIGKILL, an out-of-memory kill): call it in the process itself, or pass it as a child's
    ``preexec_fn``. A process whose parent dies first gets SIGTERM at once."""
    prctl = ctypes.CDLL(None).prctl  # looked up here: the child of a fork should only call it

    def set_parent_death_signal() -> None:
        prctl(PR_SET_PDEATHSIG, signal.SIGTERM)
        if os.getppid() != parent:  # died before the line above took effect
            os.kill(os.getpid(), signal.SIGTERM)

    return set_parent_death_signal
