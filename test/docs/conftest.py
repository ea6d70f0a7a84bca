"""Fixtures of the docs tests that run what a page or a result folder documents: the built-in sound
library, built once per data folder where it is missing (and said, not silent)."""

import subprocess
import sys
import warnings

import pytest

from m2h_ros.paths import REPO_DIR


@pytest.fixture(scope="session")
def whole_library(sound_sources):
    """The default sound library in the data folder (what scripts/evaluate.py and the examples load)."""
    from m2h_ros.core.sounds.library import SoundLibrary
    from m2h_ros.errors import CacheError

    try:
        return SoundLibrary.load()
    except CacheError as missing:
        warnings.warn(f"building the default sound library for the docs tests ({missing})", stacklevel=1)
        subprocess.run([sys.executable, str(REPO_DIR / "scripts" / "build_sound_library.py")], check=True)
        return SoundLibrary.load()
