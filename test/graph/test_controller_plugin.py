"""A controller from another package: installed out of tree with its entry point in the group
``m2h_ros.controllers``, it runs in ``scripts/evaluate.py`` and through the running graph as the
controller node's ``policy``, with nothing in this repository edited."""

from __future__ import annotations

import os
import subprocess
import sys
import textwrap

import pytest
from pipeline_helpers import ROOT, bag_messages, node_env, tiny_sets

from m2h_ros.core.world.episodes import MOVE_FORWARD, TURN_LEFT

pytestmark = pytest.mark.graph
NAME = "zigzag_plugin"
PYPROJECT = f"""
[build-system]
requires = ["setuptools"]
build-backend = "setuptools.build_meta"

[project]
name = "m2h-zigzag"
version = "0.1.0"

[project.entry-points."m2h_ros.controllers"]
{NAME} = "m2h_zigzag:ZigZag"
"""
MODULE = '''
import numpy as np

from m2h_ros.agents.base import Controller
from m2h_ros.core.world.episodes import MOVE_FORWARD, TURN_LEFT


class ZigZag(Controller):
    name = "zigzag_plugin"
    summary = "alternates MoveForward and TurnLeft (an out-of-tree plugin)"
    uses_separator = False

    def _act(self, obs):
        return np.where(obs.step % 2 == 0, MOVE_FORWARD, TURN_LEFT).astype(np.int64)
'''
# Plays the plugin with scripts/evaluate.py's own run() on two small episodes of the tiny setup (the
# full-size evaluation needs the whole sound library and the test scenes' acoustics).
EVALUATE = f'''
import importlib.util, sys
from m2h_ros.core.sounds.library import SoundLibrary, SoundLibraryConfig
from m2h_ros.core.world.env import EnvConfig
from m2h_ros.core.world.episodes import EpisodeConfig, generate_episodes
from m2h_ros.models.checkpoint import DEFAULT_SEPARATOR_CHECKPOINT, load_separator
from m2h_ros.sim_world import ACOUSTICS_PRESETS

spec = importlib.util.spec_from_file_location("evaluate_script", "{ROOT}/scripts/evaluate.py")
evaluate = importlib.util.module_from_spec(spec)
spec.loader.exec_module(evaluate)
library = SoundLibrary.load(SoundLibraryConfig.small())
episodes = generate_episodes(EpisodeConfig(task="near_target", count=2, max_steps=4, scene_split="test",
                                           scene_preset="small", min_source_distance=3.0), library)
args = evaluate.build_parser().parse_args(["--slots", "2", "--threads", "1", "--no-progress"])
results, _ = evaluate.run(args, ["{NAME}"], episodes, loaded=load_separator(DEFAULT_SEPARATOR_CHECKPOINT),
                          library=library, env_config=EnvConfig(camera=False, acoustics=ACOUSTICS_PRESETS["fast"]))
print("played", [(r.controller, len(r.si_sdr)) for r in results])
'''


@pytest.fixture(scope="module")
def plugin_path(tmp_path_factory) -> str:
    """PYTHONPATH holding the plugin package, installed by pip into a folder of its own (not the venv)."""
    source = tmp_path_factory.mktemp("m2h_zigzag")
    (source / "pyproject.toml").write_text(PYPROJECT)
    (source / "m2h_zigzag.py").write_text(textwrap.dedent(MODULE))
    target = tmp_path_factory.mktemp("site")
    subprocess.run([sys.executable, "-m", "pip", "install", "--quiet", "--no-deps", "--no-index",
                    "--no-build-isolation", "--target", str(target), str(source)], check=True, timeout=300)
    return os.pathsep.join([str(target), os.environ.get("PYTHONPATH", "")])


def with_plugin(env: dict[str, str], plugin_path: str) -> dict[str, str]:
    return {**env, "PYTHONPATH": plugin_path}


def test_evaluate_lists_and_plays_the_plugin(plugin_path, small_library, small_data_dir):
    env = with_plugin(node_env(small_data_dir), plugin_path)
    listed = subprocess.run([sys.executable, "scripts/evaluate.py", "--list"], capture_output=True, text=True,
                            env=env, cwd=ROOT, timeout=120)
    assert listed.returncode == 0, listed.stderr
    assert f"{NAME:<18} alternates MoveForward and TurnLeft (an out-of-tree plugin) (plugin: m2h_zigzag:ZigZag)" \
        in listed.stdout
    played = subprocess.run([sys.executable, "-c", EVALUATE], capture_output=True, text=True, env=env, cwd=ROOT,
                            timeout=300)
    assert played.returncode == 0, played.stdout + played.stderr
    assert f"played [('{NAME}', 5), ('{NAME}', 5)]" in played.stdout


def test_the_controller_node_runs_the_plugin_in_the_graph(plugin_path, small_library, small_data_dir, tmp_path):
    env = with_plugin(node_env(small_data_dir), plugin_path)
    result = subprocess.run([sys.executable, "scripts/run_pipeline.py", "--out", str(tmp_path), "--episodes", "1",
                             "--controller", NAME, *tiny_sets()], capture_output=True, text=True, env=env, cwd=ROOT,
                            timeout=240)
    assert result.returncode == 0, result.stdout + result.stderr
    assert f"| {NAME} | near_target | unheard | 1 |" in result.stdout
    commands = bag_messages(tmp_path / "bag")["/cmd"]
    assert commands and {c.controller for c in commands} == {NAME}
    assert [c.action for c in commands] == [MOVE_FORWARD if c.step % 2 == 0 else TURN_LEFT for c in commands]


def test_without_the_plugin_the_name_is_refused(small_data_dir):
    listed = subprocess.run([sys.executable, "scripts/evaluate.py", "--controllers", NAME, "--count", "1"],
                            capture_output=True, text=True, env=node_env(small_data_dir), cwd=ROOT, timeout=120)
    assert listed.returncode == 2 and f"unknown controller {NAME!r}" in listed.stderr
