"""Bank builds of an imported world: serial, two local processes and Ray tasks write the same bytes; a
build computes only the source files that are missing, and one interrupted keeps what it finished."""

import numpy as np
import pytest

from m2h_ros.core.world.acoustics import AcousticsConfig
from m2h_ros.core.world.bank_build import LOCAL_RAY, compute_sources
from m2h_ros.core.world.rir_bank import RirBank
from m2h_ros.core.world.ros_map import write_ros_map
from m2h_ros.core.world.sample_worlds import corridor_grid
from m2h_ros.core.world.worlds import load_world
from m2h_ros.errors import CacheError, ConfigError

# The tail is on (few rays): its scattering draws are seeded per source node, which must hold in any
# worker process.
CONFIG = AcousticsConfig(rir_length=0.25, early_length=0.064, ism_max_order=2, n_rays=100)


@pytest.fixture(scope="module")
def world(tmp_path_factory):
    path = write_ros_map(tmp_path_factory.mktemp("corridor") / "map.yaml", corridor_grid(0.8))
    return load_world(f"map:{path}")


def bank_bytes(bank: RirBank) -> dict[str, bytes]:
    return {path.name: path.read_bytes() for path in sorted(bank.directory.iterdir())}


@pytest.fixture(scope="module")
def serial(world, tmp_path_factory) -> dict[str, bytes]:
    bank = RirBank(world, CONFIG, cache_dir=tmp_path_factory.mktemp("serial"), progress=False)
    assert bank.build(workers=1) == world.grid.n_nodes
    files = bank_bytes(bank)
    assert len([name for name in files if name.startswith("src_")]) == world.grid.n_nodes
    assert "meta.json" in files
    return files


@pytest.fixture(scope="module")
def ray_session():
    import ray  # pinned in requirements.txt: a missing one is an error, not a skip
    ray.init(num_cpus=2, include_dashboard=False, log_to_driver=False, configure_logging=False)
    yield ray
    ray.shutdown()


def test_two_processes_write_the_serial_bytes(world, serial, tmp_path):
    bank = RirBank(world, CONFIG, cache_dir=tmp_path, progress=False)
    assert bank.build(workers=2) == world.grid.n_nodes
    assert bank_bytes(bank) == serial


def test_ray_tasks_write_the_serial_bytes(world, serial, tmp_path, ray_session):
    bank = RirBank(world, CONFIG, cache_dir=tmp_path, progress=False)
    assert bank.build(workers=2, ray_address=LOCAL_RAY) == world.grid.n_nodes
    assert bank_bytes(bank) == serial
    assert ray_session.is_initialized()  # a session the caller opened stays open


def test_present_files_are_kept_and_only_the_rest_computed(world, serial, tmp_path):
    bank = RirBank(world, CONFIG, cache_dir=tmp_path, progress=False)
    kept = [0, 5, 11]
    # Files that a fresh computation would never give: any recomputation of them shows.
    placeholder = np.zeros((bank.n_nodes, CONFIG.row_length), CONFIG.storage_dtype)
    for node in kept:
        bank.store(node, placeholder)
    assert bank.build(workers=2) == world.grid.n_nodes - len(kept)
    files = bank_bytes(bank)
    for node in kept:
        assert np.array_equal(np.load(bank.path(node)), placeholder)
    assert {k: v for k, v in files.items() if k not in {bank.path(n).name for n in kept}} == \
        {k: v for k, v in serial.items() if k not in {bank.path(n).name for n in kept}}


def test_an_interrupted_build_keeps_its_files_and_resumes(world, serial, tmp_path, monkeypatch):
    bank = RirBank(world, CONFIG, cache_dir=tmp_path, progress=False)
    stored = []

    def store_three_then_interrupt(node, rows):
        if len(stored) == 3:
            raise KeyboardInterrupt
        stored.append(node)
        return RirBank.store(bank, node, rows)

    monkeypatch.setattr(bank, "store", store_three_then_interrupt)
    with pytest.raises(KeyboardInterrupt):
        bank.build(workers=2)
    monkeypatch.undo()
    assert sorted(set(range(bank.n_nodes)) - set(bank.missing())) == sorted(stored)
    assert not [p for p in bank.directory.iterdir() if p.name.endswith(".tmp")]
    assert bank.build(workers=2) == bank.n_nodes - 3
    assert bank_bytes(bank) == serial


def test_rows_of_another_shape_are_refused(world, tmp_path):
    bank = RirBank(world, CONFIG, cache_dir=tmp_path, progress=False)
    with pytest.raises(CacheError, match="holds"):
        bank.store(0, np.zeros((bank.n_nodes, 3), np.float32))
    assert bank.missing() == list(range(bank.n_nodes))


@pytest.mark.parametrize("workers", [0, 1.5, True])
def test_workers_must_be_a_positive_integer(world, workers):
    with pytest.raises(ConfigError, match="workers"):
        compute_sources(world, CONFIG, [0], lambda node, rows: None, workers=workers)

