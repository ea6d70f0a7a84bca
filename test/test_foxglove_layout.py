"""The shipped Foxglove layout is what scripts/foxglove_layout.py builds with foxglove-sdk's layout types
(that each panel shows what a recorded run carries: test/graph/test_pipeline.py)."""

import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def test_the_shipped_layout_is_the_generated_one():
    result = subprocess.run([sys.executable, str(ROOT / "scripts" / "foxglove_layout.py"), "--check"],
                            capture_output=True, text=True, cwd=ROOT)
    assert result.returncode == 0, result.stderr
