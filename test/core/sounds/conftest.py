"""The --small library built once per session from the real Debian material, into a tmp data dir.

The extracted Debian packages stay in the normal sources cache (fetched once by
scripts/fetch_sound_sources.sh, which this fixture runs if they are missing)."""

import subprocess
from pathlib import Path

import pytest

from m2h_ros.core.sounds.library import SoundLibrary, SoundLibraryConfig
from m2h_ros.core.sounds.sources import check_sources, sources_dir
from m2h_ros.errors import CacheError

REPO = Path(__file__).resolve().parents[3]


@pytest.fixture(scope="session")
def sound_sources() -> Path:
    root = sources_dir()
    try:
        check_sources(root)
    except CacheError:
        subprocess.run(["bash", str(REPO / "scripts" / "fetch_sound_sources.sh"), str(root)], check=True)
    return root


@pytest.fixture(scope="session")
def small_data_dir(tmp_path_factory) -> Path:
    return tmp_path_factory.mktemp("m2h_data")


@pytest.fixture(scope="session")
def small_library(sound_sources, small_data_dir) -> SoundLibrary:
    with pytest.MonkeyPatch.context() as patch:
        patch.setenv("M2H_DATA_DIR", str(small_data_dir))
        return SoundLibrary.build(SoundLibraryConfig.small(), sources=sound_sources, progress=False)
