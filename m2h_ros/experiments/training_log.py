"""A PPO run's ``log.csv`` (``training/ppo.py`` writes one row per update), read back as floats."""

from __future__ import annotations

import csv
import math
from pathlib import Path

from m2h_ros.errors import ConfigError


def read_training_log(path: str | Path) -> list[dict[str, float]]:
    """The rows of ``path`` (a run directory or its log.csv), every cell a float (an empty one nan)."""
    path = Path(path)
    log = path / "log.csv" if path.is_dir() else path
    if not log.is_file():
        raise ConfigError(f"no training log at {log}")
    with open(log, newline="") as f:
        rows = list(csv.DictReader(f))
    if not rows or "sps" not in rows[0]:
        raise ConfigError(f"{log} holds no PPO log rows (a header with 'sps' and one row per update)")
    try:
        return [{k: math.nan if v in ("", None) else float(v) for k, v in row.items()} for row in rows]
    except ValueError as exc:
        raise ConfigError(f"{log}: {exc}") from exc
