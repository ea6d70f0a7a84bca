"""The nodes start without loading what only some of their work needs: the acoustics engine
(pyroomacoustics: building RIR banks), scipy.signal (loading a head, resampling a microphone) and
scipy.stats (confidence intervals of a results table) cost every process half a second or more each to
import, and a run starts five to seven of them."""

import subprocess
import sys

import pytest

NODES = ("sim_node", "separator_node", "controller_node", "evaluator_node", "recorder_node", "live_view_node",
         "base_node")
DEFERRED = ("pyroomacoustics", "scipy.signal", "scipy.stats", "matplotlib")


@pytest.mark.parametrize("node", NODES)
def test_a_node_imports_without_the_libraries_only_some_of_its_work_needs(node):
    code = (f"import sys, m2h_ros.nodes.{node}\n"
            f"print(','.join(n for n in {DEFERRED!r} if n in sys.modules))")
    result = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert result.returncode == 0, result.stderr
    assert result.stdout.strip() == "", f"{node} imports {result.stdout.strip()} at start"
