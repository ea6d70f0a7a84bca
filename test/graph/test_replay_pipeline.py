"""m2h-eval on a real recorded run of the five-process pipeline gives the live evaluator's scores."""

import subprocess
import sys
from pathlib import Path

import pytest

from m2h_ros.core.results import read_results
from m2h_ros.io.replay import replay_bag

pytestmark = pytest.mark.graph
ROOT = Path(__file__).resolve().parents[2]


def test_replayed_scores_equal_the_live_ones(tmp_path):
    out = tmp_path / "run"
    run = subprocess.run([sys.executable, str(ROOT / "scripts" / "run_pipeline.py"), "--episodes", "2",
                          "--out", str(out)], capture_output=True, text=True, timeout=600)
    assert run.returncode == 0, run.stdout[-3000:] + run.stderr[-3000:]
    replay = replay_bag(out / "bag")
    assert replay.problems == [] and replay.comparison.mismatches == []
    live = read_results(out / "scores" / "results.json")
    assert [r.episode_id for r in replay.results] == [r.episode_id for r in live]
    assert [r.to_dict() for r in replay.results] == [r.to_dict() for r in live]  # exactly: same code, same data
    assert replay.comparison.steps == sum(len(r.si_sdr) for r in live)
    assert replay.comparison.episodes == 2
