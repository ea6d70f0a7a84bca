"""The committed results come out of today's code: the first episodes of two result folders, replayed with
the folder's own command (fewer episodes), give the committed rows; a change to the acoustics, the
separator, a policy or the scoring that moves a result fails here, naming the folder to remake. On the
same near-target episodes each shipped learned model stays above a floor: half of its lead over random
actions there (the figures beside each floor are the committed rows' own), so a model that has become no
better than random actions fails even where a table was remade with it."""

import csv
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from m2h_ros.paths import REPO_DIR

RESULTS = REPO_DIR / "docs" / "results"
SCORES = ("final_si_sdr", "final_si_sdr_mixture_phase", "final_stft_distance", "path_length", "success")
# Batched convolutions round differently with the batch size (the folders ran 16 slots): dB to 1e-4.
TOLERANCE = 1e-4
NEAR_EPISODES = 12
NEAR_CONTROLLERS = ("stand_in_place", "random", "move2hear", "novelty", "av_navigator", "gan_et_al")
# Final SI-SDR over random actions' on the first 12 unheard near-target test episodes, mean (committed rows:
# over Stand In-Place, random +0.72 dB, move2hear +1.40, gan_et_al +2.04). AV Navigator learned to
# approach (it is no better than random at hearing here: +0.64): its rows are checked above, not floored.
NEAR_FLOORS_DB = {"move2hear": 0.34, "gan_et_al": 0.66}
# Novelty (policy_novelty.pt) is rewarded for new places: metres walked beyond random actions' (6.08 - 2.58).
NOVELTY_FLOOR_M = 1.75


def evaluate(tmp_path: Path, *args: str) -> list[dict]:
    out = tmp_path / "evaluate"
    done = subprocess.run([sys.executable, str(REPO_DIR / "scripts" / "evaluate.py"), *args, "--threads", "1",
                           "--no-progress", "--out", str(out)], capture_output=True, text=True, timeout=1800,
                          cwd=REPO_DIR)
    assert done.returncode == 0, done.stdout[-2000:] + done.stderr[-3000:]
    return list(csv.DictReader((out / "results.csv").open()))


def committed(folder: str) -> dict[tuple[str, str], dict]:
    return {(r["episode_id"], r["controller"]): r for r in csv.DictReader((RESULTS / folder / "results.csv").open())}


def assert_reproduced(rows: list[dict], folder: str) -> None:
    table = committed(folder)
    for row in rows:
        key = (row["episode_id"], row["controller"])
        assert key in table, f"{key} is not in docs/results/{folder}/results.csv"
        for score in SCORES:
            assert float(row[score]) == pytest.approx(float(table[key][score]), abs=TOLERANCE), (
                f"docs/results/{folder}: {key} {score} is {row[score]}, committed {table[key][score]}: "
                f"remake the folder with its README's command")


@pytest.fixture(scope="module")
def near_target(whole_library, tmp_path_factory) -> list[dict]:
    return evaluate(tmp_path_factory.mktemp("near"), "--controllers", ",".join(NEAR_CONTROLLERS), "--task",
                    "near_target", "--sound-split", "unheard", "--count", str(NEAR_EPISODES))


def test_the_near_target_results_reproduce(near_target):
    assert len(near_target) == len(NEAR_CONTROLLERS) * NEAR_EPISODES
    assert_reproduced(near_target, "near_target")


def _final(rows: list[dict], controller: str, score: str = "final_si_sdr") -> np.ndarray:
    chosen = sorted((r["episode_id"], float(r[score])) for r in rows if r["controller"] == controller)
    return np.array([value for _, value in chosen])


@pytest.mark.parametrize("controller", list(NEAR_FLOORS_DB))
def test_each_shipped_model_hears_better_than_random_actions(near_target, controller):
    gain = _final(near_target, controller) - _final(near_target, "random")
    print(f"{controller} over random actions: mean {gain.mean():+.2f} dB")
    assert gain.mean() > NEAR_FLOORS_DB[controller]


def test_novelty_walks_farther_than_random_actions(near_target):
    beyond = _final(near_target, "novelty", "path_length").mean() - _final(near_target, "random", "path_length").mean()
    print(f"novelty walks {beyond:+.2f} m beyond random actions")
    assert beyond > NOVELTY_FLOOR_M


def test_the_far_target_composite_rows_reproduce(whole_library, tmp_path):
    """docs/results/far_target/stand_in_place_gan_et_al's move2hear:approach rows, by the README's command."""
    walker = tmp_path / "composite_walker"
    walker.mkdir()
    default = REPO_DIR / "m2h_ros" / "models" / "default"
    (walker / "policy_quality.pt").symlink_to(default / "policy_quality.pt")
    (walker / "policy_navigation.pt").symlink_to(default / "policy_navigation_stage2.pt")
    rows = evaluate(tmp_path, "--controllers", "move2hear:approach", "--policy-checkpoint", str(walker), "--task",
                    "far_target", "--sound-split", "heard", "--count", "2")
    assert len(rows) == 2
    assert_reproduced(rows, "far_target/stand_in_place_gan_et_al")
