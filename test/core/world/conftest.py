"""Session fixtures of the environment tests: one RIR cache with fast acoustics (the small sound
library fixture is in test/conftest.py)."""

from pathlib import Path

import pytest

from m2h_ros.core.world.acoustics import AcousticsConfig

REPO = Path(__file__).resolve().parents[3]


@pytest.fixture(scope="session")
def rir_cache(tmp_path_factory) -> Path:
    return tmp_path_factory.mktemp("rir_banks")


@pytest.fixture(scope="session")
def fast_acoustics() -> AcousticsConfig:
    """Short RIRs, image sources up to order 2, no ray-traced tail: a small scene's bank builds in ~1 s."""
    return AcousticsConfig(rir_length=0.25, early_length=0.064, ism_max_order=2, tail=False)
