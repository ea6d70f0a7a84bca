"""The benchmarks' measure of free cores: the arithmetic over the workers' own timings (the timings
reported by stand-ins, so the test asserts no wall-clock interval), and the line the benchmarks print."""

import multiprocessing

import pytest

from m2h_ros import machine

# Calls of the stand-in workload so far, shared by the forked workers: the first runs alone, the next two
# side by side (cores_available's two rounds).
CALLS = multiprocessing.get_context("fork").Value("i", 0)


def _reporting(alone: float, together: tuple[float, float]):
    """A workload that reports ``alone`` seconds when run alone, then each of ``together`` when two run."""
    def spin(queue) -> None:
        with CALLS.get_lock():
            call = CALLS.value
            CALLS.value += 1
        queue.put(alone if call == 0 else together[call - 1])
    return spin


@pytest.mark.parametrize("alone, together, cores", [
    (1.0, (1.0, 1.0), 2.0),   # two workers side by side take as long as one: two cores
    (1.0, (1.0, 2.0), 1.0),   # the second waits for the first: they share one core (the slower one counts)
    (0.5, (0.8, 0.6), 1.25),  # a busy second core
])
def test_the_reading_is_two_times_one_workers_time_over_the_slower_of_two(monkeypatch, alone, together, cores):
    CALLS.value = 0
    monkeypatch.setattr(machine, "_spin", _reporting(alone, together))
    assert machine.cores_available() == pytest.approx(cores)
    assert CALLS.value == 3  # one alone, then two at once


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


def _report_peak(queue) -> None:
    queue.put(machine.peak_rss_mib())


def test_a_spawned_process_reports_its_own_peak_not_its_parents():
    held = bytearray(400 * 2**20)   # the parent holds 400 MiB, touched, when it spawns
    held[::4096] = b"\x01" * len(held[::4096])
    assert machine.peak_rss_mib() >= 400
    context = multiprocessing.get_context("spawn")
    queue = context.Queue()
    child = context.Process(target=_report_peak, args=(queue,))
    child.start()
    child_peak = queue.get(timeout=60)
    child.join()
    assert child_peak < 300, f"the child reported {child_peak:.0f} MiB, its parent's memory"
