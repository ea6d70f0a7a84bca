#!/usr/bin/env python3
"""Summary of PPO training runs from their log.csv (one row per update): env steps, the rate of the
updates (median, and of the first and last 100), and the mean of a few figures over the last updates.

    python scripts/run_summary.py docs/results/training/policy_quality/stage1 docs/results/training/policy_quality/stage2 [--last 250]

A run directory or its log.csv. A figure the run's kind does not log (empty or nan) prints as "-".
"""

from __future__ import annotations

import argparse
import math
import statistics
import sys
from pathlib import Path

from m2h_ros.errors import ConfigError
from m2h_ros.experiments.training_log import read_training_log

RATE_WINDOW = 100
MEAN_COLUMNS = ("return_window", "location_error_m", "success_window")


def read_log(path: Path) -> list[dict[str, float]]:
    try:
        return read_training_log(path)
    except ConfigError as exc:
        raise SystemExit(f"run_summary: {exc}") from exc


def mean_of_last(rows: list[dict[str, float]], column: str) -> float:
    values = [row[column] for row in rows if column in row and not math.isnan(row[column])]
    return statistics.fmean(values) if values else math.nan


def summary(rows: list[dict[str, float]], *, last: int) -> dict[str, float]:
    rates = [row["sps"] for row in rows]
    figures = {"updates": len(rows), "env_steps": int(rows[-1]["env_steps"]),
               "median_sps": statistics.median(rates),
               f"first_{RATE_WINDOW}_sps": statistics.median(rates[:RATE_WINDOW]),
               f"last_{RATE_WINDOW}_sps": statistics.median(rates[-RATE_WINDOW:])}
    figures.update({f"{column}_last_{last}": mean_of_last(rows[-last:], column) for column in MEAN_COLUMNS})
    return figures


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("runs", nargs="+", type=Path, help="run directories (or their log.csv)")
    parser.add_argument("--last", type=int, default=250, help="updates the means are taken over")
    args = parser.parse_args(argv)
    tables = {str(run): summary(read_log(run), last=args.last) for run in args.runs}
    columns = list(next(iter(tables.values())))
    print("| run | " + " | ".join(columns) + " |")
    print("|---" * (len(columns) + 1) + "|")
    for run, figures in tables.items():
        cells = ["-" if isinstance(v, float) and math.isnan(v) else f"{v:.2f}" if isinstance(v, float) else str(v)
                 for v in figures.values()]
        print(f"| {run} | " + " | ".join(cells) + " |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
