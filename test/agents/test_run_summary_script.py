"""scripts/run_summary.py: the figures of a PPO run's log.csv that the README quotes."""

import csv

import pytest


@pytest.fixture(scope="module")
def run_summary(script):
    return script("run_summary")


def write_log(directory, rates, returns):
    directory.mkdir()
    with open(directory / "log.csv", "w", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=["update", "env_steps", "return_window", "location_error_m",
                                               "success_window", "sps"])
        writer.writeheader()
        for update, (rate, ret) in enumerate(zip(rates, returns), 1):
            writer.writerow({"update": update, "env_steps": 640 * update, "return_window": ret,
                             "location_error_m": "nan", "success_window": "", "sps": rate})
    return directory


def test_rates_and_means_of_the_last_updates(run_summary, tmp_path, capsys):
    # 150 updates: the first 100 at 100-199 env steps/s, the last 50 at 400; returns 0 then 1.
    run = write_log(tmp_path / "run", [100 + i for i in range(100)] + [400] * 50, [0.0] * 100 + [1.0] * 50)
    figures = run_summary.summary(run_summary.read_log(run), last=100)
    assert figures["updates"] == 150 and figures["env_steps"] == 96_000
    assert figures["median_sps"] == 174.5 and figures["first_100_sps"] == 149.5
    assert figures["last_100_sps"] == (199 + 400) / 2  # 150-199 and fifty 400s
    assert figures["return_window_last_100"] == 0.5
    assert run_summary.main([str(run / "log.csv"), "--last", "100"]) == 0
    line = capsys.readouterr().out.splitlines()[-1]
    assert line.startswith(f"| {run / 'log.csv'} | 150 | 96000 | 174.50 |") and line.endswith("| 0.50 | - | - |")


def test_a_missing_or_foreign_log_is_named(run_summary, tmp_path):
    with pytest.raises(SystemExit, match="no training log at"):
        run_summary.read_log(tmp_path)
    (tmp_path / "log.csv").write_text("a,b\n1,2\n")
    with pytest.raises(SystemExit, match="holds no PPO log rows"):
        run_summary.read_log(tmp_path)


def test_a_cell_that_is_no_number_is_named(run_summary, tmp_path):
    (tmp_path / "log.csv").write_text("update,sps\n1,fast\n")
    with pytest.raises(SystemExit, match=r"log.csv: could not convert string to float: 'fast'"):
        run_summary.read_log(tmp_path)
