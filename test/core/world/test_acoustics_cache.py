"""RirBank: lazy computation, on-disk cache round trip, corruption detection, gather shapes."""

import os

import numpy as np
import pytest

from m2h_ros.core.sounds.sources import sources_dir
from m2h_ros.core.world.acoustics import AcousticsConfig, assemble, simulate_source
from m2h_ros.core.world.rir_bank import RirBank, bank_dir
from m2h_ros.core.world.scene import generate_scene
from m2h_ros.errors import CacheError, ConfigError

CONFIG = AcousticsConfig(n_rays=100, ism_max_order=2, rir_length=0.25, early_length=0.08, storage_dtype="float16")


@pytest.fixture(scope="module")
def scene():
    return generate_scene(0, preset="small")


@pytest.fixture()
def data_root(tmp_path, monkeypatch):
    # The banks go to a fresh data dir; the KEMAR HRTF they are rendered with stays where setup put it.
    (tmp_path / "sound_sources").symlink_to(sources_dir())
    monkeypatch.setenv("M2H_DATA_DIR", str(tmp_path))
    return tmp_path


def test_cache_round_trip_and_gather(scene, data_root):
    bank = RirBank(scene, CONFIG, progress=False)
    assert bank.directory == bank_dir(scene, CONFIG)
    assert str(bank.directory).startswith(str(data_root / "rir_banks" / "v"))
    n = len(scene.grid.positions)
    assert bank.missing() == list(range(n))
    bank.build(progress=False, workers=2)
    assert bank.missing() == []
    mtimes = [bank.path(i).stat().st_mtime_ns for i in range(n)]

    rng = np.random.default_rng(1)
    sources, receivers, headings = rng.integers(0, n, 12), rng.integers(0, n, 12), rng.integers(0, 4, 12)
    first = bank.rirs(sources, receivers, headings)
    assert first.shape == (12, 2, CONFIG.n_taps) and first.dtype == np.float32

    reloaded = RirBank(scene, CONFIG, progress=False)  # same scene + settings: loads from disk
    second = reloaded.rirs(sources, receivers, headings)
    assert np.array_equal(first, second)
    assert [bank.path(i).stat().st_mtime_ns for i in range(n)] == mtimes
    assert isinstance(reloaded._source(int(sources[0])).base, np.memmap)   # a view of the mapped file

    # A gathered RIR equals the directly simulated one.
    rows = simulate_source(scene, int(sources[0]), CONFIG)
    direct = assemble(rows[[receivers[0]]], headings[:1], CONFIG)
    assert np.array_equal(first[:1], direct)
    assert bank.size_on_disk() == sum(bank.path(i).stat().st_size for i in range(n))


def test_lazy_computation_and_index_checks(scene, data_root):
    bank = RirBank(scene, CONFIG, progress=False)
    out = bank.rirs([1, 1], [0, 2], [0, 3])
    assert out.shape == (2, 2, CONFIG.n_taps)
    assert bank.path(1).exists() and not bank.path(0).exists()
    with pytest.raises(ConfigError, match="heading"):
        bank.rirs([1], [0], [4])
    with pytest.raises(ConfigError, match="source"):
        bank.rirs([len(scene.grid.positions)], [0], [0])


def test_settings_change_the_cache_key(scene, data_root):
    other = AcousticsConfig(n_rays=100, ism_max_order=1, rir_length=0.25, early_length=0.08)
    assert bank_dir(scene, CONFIG) != bank_dir(scene, other)
    assert bank_dir(scene, CONFIG) != bank_dir(generate_scene(1, preset="small"), CONFIG)


@pytest.mark.parametrize("damage", ["truncate", "garbage"])
def test_corrupt_cache_file_is_detected(scene, data_root, damage):
    bank = RirBank(scene, CONFIG, progress=False)
    bank.rirs([0], [0], [0])
    path = bank.path(0)
    if damage == "truncate":
        with open(path, "r+b") as handle:
            handle.truncate(path.stat().st_size // 2)
    else:
        path.write_bytes(os.urandom(256))
    with pytest.raises(CacheError, match=str(path.name)):
        RirBank(scene, CONFIG, progress=False).rirs([0], [0], [0])


def test_no_temporary_files_left(scene, data_root):
    bank = RirBank(scene, CONFIG, progress=False)
    bank.rirs([2], [0], [0])
    assert not [p for p in bank.directory.iterdir() if p.name.endswith(".tmp")]
