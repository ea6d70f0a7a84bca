"""The Python API page's example runs as it stands on the page, with the built-in sound library and the
shipped separator, and prints what it says it prints."""

import os
import re
import subprocess
import sys

from m2h_ros.paths import REPO_DIR

PAGE = REPO_DIR / "docs" / "reference" / "python.md"


def test_the_python_reference_example_runs(whole_library):
    example = re.search(r"## Example\n.*?```python\n(.*?)```", PAGE.read_text(), re.S).group(1)
    result = subprocess.run([sys.executable, "-c", example], capture_output=True, text=True, timeout=600,
                            cwd=REPO_DIR, env={**os.environ, "OMP_WAIT_POLICY": "PASSIVE"})
    assert result.returncode == 0, result.stderr[-3000:]
    lines = result.stdout.splitlines()
    assert re.fullmatch(r"random walk, last step: mixture SI-SDR -?\d+\.\d\d dB", lines[0]), lines
    scored = [re.fullmatch(r"test/near_target/unheard/\S+: final SI-SDR (-?\d+\.\d\d) dB", line) for line in lines[1:]]
    assert len(scored) == 2 and all(scored), lines
