"""The benchmarks' measure of free cores."""

import os

from m2h_ros import machine


def test_cores_available_is_a_share_of_the_cpus():
    cores = machine.cores_available()
    # Two processes of the same work get at most all CPUs (plus timing noise) and at least one's worth
    # shared: on one busy core the pair takes twice as long as one, which reads 1.0.
    assert 0.3 < cores <= min(os.cpu_count(), 2) * 1.25


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
