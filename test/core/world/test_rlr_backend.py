"""The rlr acoustics backend (RLRAudioPropagation): bank layout, rate and keys, interaural cues, materials,
backend separation, and the clear error where the opt-in package is not installed."""

import sys

import numpy as np
import pytest

from m2h_ros.core.sounds.sources import sources_dir
from m2h_ros.core.world import rlr_backend
from m2h_ros.core.world.acoustics import (
    BAND_CENTRES,
    AcousticsConfig,
    _effective_faces,
    _face_area,
    assemble,
    measure_rt60,
    octave_band,
    receiver_positions,
    room_rt60,
    simulate_source,
)
from m2h_ros.core.world.rir_bank import RirBank, bank_dir
from m2h_ros.core.world.scene import build_scene
from m2h_ros.core.world.worlds import load_world
from m2h_ros.paths import REPO_DIR
from m2h_ros.errors import ConfigError
from m2h_ros.node_configs import SimConfig
from m2h_ros.sim_world import env_config
from scripts_as_modules import load_script

FS = 16000
C = 343.0
SHORT = dict(rir_length=0.5, early_length=0.064, rlr_rays=500)
installed = pytest.mark.skipif(not rlr_backend.available(),
                               reason="rlr-audio-propagation is not installed (opt-in, CC-BY-NC 4.0: "
                                      "scripts/setup.sh --with-rlr; scripts/test.sh installs it)")


def _room(wall: str, floor: str = "carpet_cotton", ceiling: str = "ceiling_plasterboard"):
    """One 4 m x 3 m room (12 nodes at the cell centres), 2.5 m high as every generated scene."""
    return build_scene(np.zeros((4, 3), dtype=int), surfaces=[(wall, floor, ceiling, (1.0, 0.0, 0.0))])


def _node(scene, xy) -> int:
    return int(np.flatnonzero((scene.grid.positions == np.asarray(xy)).all(axis=1))[0])


def _onset(rir: np.ndarray) -> int:
    """First sample where either ear reaches 20 % of the response's peak."""
    envelope = np.abs(rir).max(axis=0)
    return int(np.argmax(envelope >= 0.2 * envelope.max()))


def _direct_cues(rir: np.ndarray) -> tuple[float, float]:
    """(ITD s, ILD dB) of the direct sound: positive when it reaches the left ear first / louder."""
    start = _onset(rir)
    direct = rir[:, start - 4: start + 40].astype(np.float64)  # before the first reflection
    ild = 10 * np.log10((direct[0] ** 2).sum() / (direct[1] ** 2).sum())
    xcorr = np.correlate(np.repeat(direct[1], 8), np.repeat(direct[0], 8), mode="full")
    return (np.argmax(xcorr) - (8 * direct.shape[1] - 1)) / (8 * FS), ild


@pytest.fixture()
def data_root(tmp_path, monkeypatch):
    (tmp_path / "sound_sources").symlink_to(sources_dir())  # the KEMAR SOFA file stays where setup put it
    monkeypatch.setenv("M2H_DATA_DIR", str(tmp_path))
    return tmp_path


@pytest.fixture(scope="module")
def room_rows():
    scene = _room("plasterboard")
    config = AcousticsConfig(backend="rlr", **SHORT)
    return scene, config, simulate_source(scene, _node(scene, (2.5, 1.5)), config)


@pytest.mark.parametrize("choose", [lambda: AcousticsConfig(backend="rlr"),
                                    lambda: SimConfig(acoustics_backend="rlr")], ids=["acoustics", "sim_node"])
def test_missing_package_is_an_error_naming_the_install_step_and_licence(monkeypatch, choose):
    monkeypatch.setitem(sys.modules, "rlr_audio_propagation", None)  # an import of it now fails
    with pytest.raises(ConfigError, match=r"setup\.sh --with-rlr") as caught:
        choose()
    assert "CC-BY-NC 4.0" in str(caught.value)


@installed
def test_the_sim_nodes_backend_reaches_its_acoustics():
    assert env_config(SimConfig(acoustics_backend="rlr", acoustics="fast")).acoustics.backend == "rlr"
    assert env_config(SimConfig()).acoustics == AcousticsConfig()


def test_backend_settings_are_validated():
    with pytest.raises(ConfigError, match="backend"):
        AcousticsConfig(backend="pyroom")
    with pytest.raises(ConfigError, match="rlr_rays"):
        AcousticsConfig(rlr_rays=0)
    with pytest.raises(ConfigError, match="rlr_threads"):
        AcousticsConfig(rlr_threads=1.5)
    with pytest.raises(ConfigError, match="rlr_sh_order"):
        AcousticsConfig(rlr_sh_order=0)


def test_project_key_does_not_depend_on_rlr_settings():
    project = AcousticsConfig()
    assert project.digest() == AcousticsConfig(rlr_rays=17, rlr_threads=2, rlr_sh_order=3).digest()


@installed
def test_rows_have_the_banks_shape_rate_and_keys(room_rows):
    scene, config, rows = room_rows
    assert rows.shape == (len(scene.grid.positions), config.row_length)
    assert rows.dtype == np.dtype(config.storage_dtype)
    assert np.isfinite(rows.astype(np.float32)).all()
    # Rate: the direct sound 2 m away arrives 2 m / c later, in samples of config.sample_rate.
    rir = assemble(rows[[_node(scene, (0.5, 1.5))]], np.array([0]), config)[0]
    assert rir.shape == (2, config.n_taps)
    assert abs(_onset(rir) - 2.0 / C * FS) <= 3
    # Headings differ in the early part only; the late part is shared.
    turned = assemble(rows[[_node(scene, (0.5, 1.5))]], np.array([1]), config)[0]
    assert not np.allclose(rir[:, :config.n_early], turned[:, :config.n_early])
    assert np.array_equal(rir[:, config.n_early:], turned[:, config.n_early:])
    # Keys: the backend and its settings change the digest; threads (speed only) do not.
    assert config.digest() != AcousticsConfig(**{**SHORT, "rlr_rays": 500}).digest()
    assert config.digest() != AcousticsConfig(backend="rlr", **{**SHORT, "rlr_rays": 400}).digest()
    assert config.digest() == AcousticsConfig(backend="rlr", rlr_threads=2, **SHORT).digest()
    # The indirect field's order is keyed where set; RLR's default order keeps the digest banks had.
    assert config.digest() != AcousticsConfig(backend="rlr", rlr_sh_order=3, **SHORT).digest()
    assert config.digest() == AcousticsConfig(backend="rlr", rlr_sh_order=1, **SHORT).digest()


def test_compare_engines_settings_are_acoustics_fields_read_as_yaml():
    overrides = load_script("compare_engines").config_overrides
    assert overrides(["wall_transmission_db=inf", "air_absorption=false", "rlr_sh_order=3"]) == {
        "wall_transmission_db": float("inf"), "air_absorption": False, "rlr_sh_order": 3}
    with pytest.raises(ConfigError, match="did you mean 'air_absorption'"):
        overrides(["air_absorbtion=false"])
    with pytest.raises(ConfigError, match="FIELD=VALUE"):
        overrides(["backend=rlr"])  # both engines run: the backend is not a setting here


@installed
def test_source_ahead_reaches_both_ears_together_and_left_reaches_left_ear_first_and_louder(room_rows):
    scene, config, rows = room_rows
    receiver = rows[[_node(scene, (0.5, 1.5))]]  # the source at (2.5, 1.5) is 2 m along +x
    ahead = assemble(receiver, np.array([0]), config)[0]  # facing +x
    left = assemble(receiver, np.array([3]), config)[0]  # facing -y: +x is on the left
    right = assemble(receiver, np.array([1]), config)[0]  # facing +y: +x is on the right
    itd, ild = _direct_cues(ahead)
    assert abs(itd) < 0.05e-3 and abs(ild) < 1.0
    itd, ild = _direct_cues(left)
    assert 0.3e-3 < itd < 0.85e-3 and ild > 3.0
    itd, ild = _direct_cues(right)
    assert -0.85e-3 < itd < -0.3e-3 and ild < -3.0


@installed
def test_more_absorbent_material_shortens_the_decay():
    config = AcousticsConfig(backend="rlr", rir_length=1.0, early_length=0.064, rlr_rays=1000)
    decays = {}
    for wall in ("hard_surface", "panel_fabric_covered_6pcf"):
        scene = _room(wall, floor="hard_surface", ceiling="hard_surface")
        rows = simulate_source(scene, _node(scene, (0.5, 0.5)), config)
        rir = assemble(rows[[_node(scene, (3.5, 2.5))]], np.array([0]), config)[0].astype(np.float64)
        decays[wall] = measure_rt60(octave_band(rir[0], 1000.0, FS), FS)
        if wall == "hard_surface":
            # Reverberant enough to compare with the project's Eyring formula on the same faces.
            assert decays[wall] == pytest.approx(room_rt60(scene, 0)[list(BAND_CENTRES).index(1000.0)], rel=0.5)
    assert decays["panel_fabric_covered_6pcf"] < 0.6 * decays["hard_surface"]


@installed
def test_a_bank_of_one_backend_is_never_read_for_the_other(data_root):
    scene = _room("plasterboard")
    project = AcousticsConfig(rir_length=0.5, early_length=0.064, ism_max_order=1, tail=False)
    rlr = AcousticsConfig(backend="rlr", rir_length=0.5, early_length=0.064, ism_max_order=1, tail=False,
                          rlr_rays=200)
    assert bank_dir(scene, project) != bank_dir(scene, rlr)
    project_bank = RirBank(scene, project, progress=False)
    from_project = project_bank.rirs([0], [5], [0])
    rlr_bank = RirBank(scene, rlr, progress=False)
    assert rlr_bank.missing() == list(range(len(scene.grid.positions)))  # nothing of the project's is seen
    from_rlr = rlr_bank.rirs([0], [5], [0])
    assert rlr_bank.path(0).exists() and project_bank.path(0).exists() and rlr_bank.path(0) != project_bank.path(0)
    assert not np.allclose(from_project, from_rlr)
    assert np.array_equal(RirBank(scene, project, progress=False).rirs([0], [5], [0]), from_project)


def test_every_face_of_an_imported_world_is_triangulated_whole_with_its_own_material():
    scene = load_world(f"map:{REPO_DIR / 'docs' / 'worlds' / 'apartment' / 'map.yaml'}")
    faces = _effective_faces(scene)
    vertices, parts, materials = rlr_backend.scene_geometry(scene, AcousticsConfig())
    triangles = np.vstack(list(parts.values()))
    edges = vertices[triangles[:, 1:]] - vertices[triangles[:, :1]]
    area = 0.5 * np.linalg.norm(np.cross(edges[:, 0], edges[:, 1]), axis=-1).sum()
    assert area == pytest.approx(sum(_face_area(np.asarray(corners)) for _, corners, _, _ in faces), rel=1e-6)
    assert len(materials) == len({tuple(np.round(a, 6)) for *_, a in faces}) == len(parts)
    absorption = sorted(tuple(float(v) for v in np.round(m["absorption"][1::2], 6)) for m in materials)
    assert absorption == sorted({tuple(float(v) for v in np.round(a, 6)) for *_, a in faces})


@installed
def test_an_imported_world_renders_with_the_direct_sound_at_distance_over_c(data_root):
    scene = load_world(f"map:{REPO_DIR / 'docs' / 'worlds' / 'apartment' / 'map.yaml'}")
    config = AcousticsConfig(backend="rlr", **SHORT)
    points = receiver_positions(scene, config)
    source = 0
    same_room = np.flatnonzero((scene.grid.room_of == scene.grid.room_of[source])
                               & (np.linalg.norm(points - points[source], axis=1) >= 1.0))[:2]
    rirs = rlr_backend.render(scene, points[source], points[same_room], config)
    assert rirs.shape == (len(same_room), 4, 2, config.n_taps) and np.isfinite(rirs).all()
    for rir, receiver in zip(rirs[:, 0], same_room):
        distance = np.linalg.norm(points[receiver] - points[source])
        assert abs(_onset(rir) - distance / C * FS) <= 3
