"""scripts/evaluate.py: clear errors, and every controller end to end on a tiny setup."""

import dataclasses
import json
from pathlib import Path

import numpy as np
import pytest

from m2h_ros.agents.learned import DEFAULT_POLICY_DIR
from m2h_ros.agents.registry import CONTROLLER_NAMES, GREEDY, LEARNED, SUPERVISED, TRAINING_FREE
from m2h_ros.core.results import write_results
from m2h_ros.errors import ConfigError


@pytest.fixture(scope="module")
def evaluate(script):
    return script("evaluate")


def test_unknown_controller_and_missing_checkpoint_are_clear_errors(evaluate, tmp_path, capsys):
    assert evaluate.main(["--controllers", "random,teleport", "--out", str(tmp_path)]) == 2
    assert "unknown controller 'teleport'; available: stand_in_place" in capsys.readouterr().err
    assert evaluate.main(["--sound-split", "seen", "--out", str(tmp_path)]) == 2
    assert "unknown sound split 'seen'" in capsys.readouterr().err
    missing = tmp_path / "nope.pt"
    assert evaluate.main(["--checkpoint", str(missing), "--out", str(tmp_path)]) == 2
    assert f"checkpoint {missing} not found" in capsys.readouterr().err
    assert not list(tmp_path.iterdir())


def test_list_names_every_controller(evaluate, capsys):
    assert evaluate.main(["--list"]) == 0
    out = capsys.readouterr().out
    assert all(name in out for name in CONTROLLER_NAMES if not name.endswith(GREEDY)) and GREEDY in out


def test_every_controller_end_to_end_on_tiny_episodes(evaluate, small_episodes, folder_library, env_config, separator,
                                                      tmp_path):
    episodes = small_episodes(count=2, max_steps=3, seed=5)
    controllers = [*TRAINING_FREE, *LEARNED, *SUPERVISED]  # the learned ones with the shipped models
    args = evaluate.build_parser().parse_args(["--slots", "2", "--threads", "1", "--no-progress"])
    env_config = dataclasses.replace(env_config, camera=True)  # the learned ones and Gan et al. see
    results, model_files = evaluate.run(args, controllers, episodes, loaded=separator, library=folder_library,
                                        env_config=env_config)
    assert {name: files for name, files in model_files.items() if not files} == {name: [] for name in TRAINING_FREE}
    shipped = Path(DEFAULT_POLICY_DIR).resolve()
    for name in (*LEARNED, *SUPERVISED):  # each ran its shipped model
        assert model_files[name] and all(Path(f).resolve().parent == shipped for f in model_files[name]), name
    assert [(r.controller, r.episode_id) for r in results] == [(c, e.episode_id) for c in controllers
                                                               for e in episodes]
    assert all(np.isfinite(r.final("si_sdr")) for r in results)
    results = [r for r in results if r.controller in TRAINING_FREE]  # the tables of the baselines
    paths = write_results(results, tmp_path, title="tiny", command="python scripts/evaluate.py --count 2",
                          reference="stand_in_place")
    table = paths["markdown"].read_text()
    paired = json.loads(paths["json"].read_text())["paired"]
    assert [row["controller"] for row in paired] == [c for c in TRAINING_FREE if c != "stand_in_place"]
    stand = {r.episode_id: r.final("si_sdr") for r in results if r.controller == "stand_in_place"}
    rotate = [r.final("si_sdr") - stand[r.episode_id] for r in results if r.controller == "rotate_in_place"]
    assert paired[0]["difference"] == pytest.approx(np.mean(rotate)) and paired[0]["episodes"] == 2
    assert f"| rotate_in_place | near_target | unheard | 2 | {np.mean(rotate):+.2f} ±" in table
    assert table.splitlines()[2] == "Command: `python scripts/evaluate.py --count 2`"
    assert all(f"| {name} | near_target | unheard | 2 |" in table for name in TRAINING_FREE)
    summary = json.loads(paths["json"].read_text())["summary"]
    assert len(summary) == len(TRAINING_FREE)
    assert all(np.isfinite(row["si_sdr"]) and row["success_rate"] is None for row in summary)
    assert paths["plot"].stat().st_size > 0
    stand = [r for r in results if r.controller == "stand_in_place"]
    assert all(r.path_length == 0 for r in stand)


def test_episodes_come_from_the_chosen_scene_split(evaluate, folder_library):
    val = evaluate.select_episodes("near_target", "unheard", first=0, count=3, library=folder_library, scene_split="val")
    test = evaluate.select_episodes("near_target", "unheard", first=0, count=3, library=folder_library)
    assert all(e.scene_id.startswith("val_") for e in val) and all(e.scene_id.startswith("test_") for e in test)
    train = evaluate.select_episodes("far_target", "heard", first=0, count=3, library=folder_library,
                                     scene_split="train24")  # the training scenes, a diagnostic
    assert all(e.scene_id.startswith("train24_") for e in train)
    assert evaluate.build_parser().parse_args(["--scene-split", "train"]).scene_split == "train"
    with pytest.raises(ConfigError, match="near_target unheard val episodes"):
        evaluate.select_episodes("near_target", "unheard", first=0, count=10**6, library=folder_library,
                                 scene_split="val")
