"""Fixtures of the controller tests: small scenes, the synthetic folder library (test/conftest.py),
fast acoustics without camera, one data dir per session (RIR banks are built once), the shipped
separator."""

import importlib.util
from pathlib import Path

import pytest

from m2h_ros.core.world.env import EnvConfig
from m2h_ros.core.world.episodes import EpisodeConfig, generate_episodes

SMALL = dict(scene_split="test", scene_preset="small", min_source_distance=3.0)
SCRIPTS = Path(__file__).resolve().parents[2] / "scripts"


@pytest.fixture(scope="session")
def script():
    """``script("evaluate")``: scripts/evaluate.py loaded as a module (scripts are not a package)."""
    def load(name: str):
        spec = importlib.util.spec_from_file_location(f"{name}_script", SCRIPTS / f"{name}.py")
        module = importlib.util.module_from_spec(spec)
        spec.loader.exec_module(module)
        return module
    return load


@pytest.fixture(scope="session")
def agents_data_dir(tmp_path_factory) -> Path:
    return tmp_path_factory.mktemp("agents_data")


@pytest.fixture(scope="session")
def sources_folder() -> Path:
    """Where the sound sources and the HRTF are (not fetched: the tests of the real library ask for
    ``sound_sources``, which fetches them; the others need only the HRTF scripts/setup.sh put there)."""
    from m2h_ros.core.sounds.sources import sources_dir

    return sources_dir()


@pytest.fixture(autouse=True)
def _data_dir(monkeypatch, agents_data_dir, sources_folder):
    monkeypatch.setenv("M2H_DATA_DIR", str(agents_data_dir))
    monkeypatch.setenv("M2H_SOUND_SOURCES", str(sources_folder))  # the HRTF stays where it is


@pytest.fixture(scope="session")
def env_config(fast_acoustics) -> EnvConfig:
    return EnvConfig(camera=False, acoustics=fast_acoustics, shuffle=False)


@pytest.fixture(scope="session")
def separator():
    from m2h_ros.models.checkpoint import DEFAULT_SEPARATOR_CHECKPOINT, load_separator

    return load_separator(DEFAULT_SEPARATOR_CHECKPOINT)


@pytest.fixture(scope="session")
def small_episodes(folder_library):
    """``small_episodes(count=, max_steps=, task=, seed=, library=)``: episodes on the small test scenes,
    of the synthetic folder library unless another is given."""
    def make(*, count: int, max_steps: int, task: str = "near_target", seed: int = 0, library=folder_library):
        extra = {"near_radius": 2.0} if task == "near_target" else {"far_min_distance": 3.0}
        return generate_episodes(EpisodeConfig(task=task, count=count, max_steps=max_steps, seed=seed,
                                               **SMALL, **extra), library)
    return make
