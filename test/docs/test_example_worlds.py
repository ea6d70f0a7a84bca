"""The example worlds in docs/worlds are what scripts/make_example_worlds.py writes, and each loads."""

from __future__ import annotations

from pathlib import Path

import pytest
from scripts_as_modules import load_script

ROOT = Path(__file__).resolve().parents[2]


@pytest.fixture(scope="module")
def written(tmp_path_factory):
    module = load_script("make_example_worlds")
    out = tmp_path_factory.mktemp("worlds")
    return out, module.write_examples(out)


def test_the_committed_example_worlds_are_what_the_script_writes(written):
    out, _ = written
    fresh = sorted(p.relative_to(out) for p in out.rglob("*") if p.is_file())
    committed = sorted(p.relative_to(ROOT / "docs" / "worlds") for p in (ROOT / "docs" / "worlds").rglob("*")
                       if p.is_file())
    assert fresh == committed
    for name in fresh:
        assert (out / name).read_bytes() == (ROOT / "docs" / "worlds" / name).read_bytes(), name


def test_each_example_world_loads_with_a_connected_lattice(written):
    from m2h_ros.core.world.worlds import load_world_with_report

    _, specs = written
    for name, spec in specs.items():
        world, report = load_world_with_report(spec)
        assert world.imported and world.grid.n_nodes >= 20 and len(world.rooms) >= 4, (name, report.describe())
