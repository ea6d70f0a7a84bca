"""Session fixtures of the environment tests: one RIR cache (the fast acoustics and the small sound
library fixtures are in test/conftest.py)."""

from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[3]


@pytest.fixture(scope="session")
def rir_cache(tmp_path_factory) -> Path:
    return tmp_path_factory.mktemp("rir_banks")

