"""The machine a training run ran on, as its ``config.json`` / checkpoint metadata records it."""

from __future__ import annotations

import os
import platform
from pathlib import Path
from typing import Any

import torch


def machine_description() -> dict[str, Any]:
    """CPU model and count, platform, Python and torch versions (wall times mean little without them)."""
    model = platform.processor() or platform.machine()
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                model = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    return {"cpu_model": model, "cpu_count": os.cpu_count(), "platform": platform.platform(),
            "python": platform.python_version(), "torch": str(torch.__version__)}
