"""The benchmarks' measure of free cores."""

import multiprocessing
import time

from m2h_ros import machine

# Held by whichever worker is "on the core": stands in for two processes sharing one busy core.
ONE_CORE = multiprocessing.get_context("fork").Lock()
# Long beside a busy machine's process start-up: the second worker, started late by d seconds, still waits
# HOLD_S - d for the core, so the reading stays near one (2 * HOLD_S / (2 * HOLD_S - d)).
HOLD_S = 1.0


def _waits(queue) -> None:
    """A workload that needs no CPU: two of them take as long as one, whatever the machine's load."""
    start = time.perf_counter()
    time.sleep(HOLD_S)
    queue.put(time.perf_counter() - start)


def _waits_for_the_core(queue) -> None:
    start = time.perf_counter()
    with ONE_CORE:
        time.sleep(HOLD_S)
    queue.put(time.perf_counter() - start)


def test_two_workers_that_run_side_by_side_read_two_cores(monkeypatch):
    monkeypatch.setattr(machine, "_spin", _waits)
    assert 1.6 < machine.cores_available() < 2.4


def test_two_workers_that_share_one_core_read_one(monkeypatch):
    monkeypatch.setattr(machine, "_spin", _waits_for_the_core)
    assert 0.8 < machine.cores_available() < 1.2  # started one after the other, they would read 2.0


def test_the_line_names_the_scheduler(monkeypatch, tmp_path):
    flag = tmp_path / "sched_autogroup_enabled"
    flag.write_text("1\n")
    monkeypatch.setattr(machine, "AUTOGROUP", flag)
    monkeypatch.setattr(machine, "cores_available", lambda: 1.5)
    assert machine.availability_line().startswith("cores available to two processes: 1.50 of")
    assert "autogroup scheduling on: start benches with setsid" in machine.availability_line()
    flag.write_text("0\n")
    assert "autogroup scheduling off)" in machine.availability_line()
    monkeypatch.setattr(machine, "AUTOGROUP", tmp_path / "absent")
    assert not machine.autogroup_scheduling()
