"""Binaural RIRs: propagation delay, interaural cues, reverberation time, walls, doors, rendering."""

import numpy as np
import pytest
from scipy.signal import fftconvolve

from m2h_ros.core.world.acoustics import (
    BAND_CENTRES,
    AcousticsConfig,
    assemble,
    measure_rt60,
    mix,
    octave_band,
    render_binaural,
    room_rt60,
    simulate_source,
)
from m2h_ros.core.world.scene import build_scene
from m2h_ros.errors import ConfigError

FS = 16000
C = 343.0
CONFIG = AcousticsConfig(n_rays=300)
SURFACES = [("plasterboard", "carpet_cotton", "ceiling_plasterboard", (1.0, 0.0, 0.0)),
            ("plasterboard", "carpet_cotton", "ceiling_plasterboard", (0.0, 1.0, 0.0))]
SOURCE_XY = (4.5, 0.5)


@pytest.fixture(scope="module")
def two_rooms():
    """Room 0 is x in [0, 6), room 1 is x in [6, 10), y in [0, 4); one door at (5..6, 3)."""
    labels = np.zeros((10, 4), dtype=int)
    labels[6:] = 1
    scene = build_scene(labels, doors=[((5, 3), (6, 3))], surfaces=SURFACES)
    source = _node(scene, SOURCE_XY)
    return scene, simulate_source(scene, source, CONFIG)


def _node(scene, xy) -> int:
    return int(np.flatnonzero((scene.grid.positions == np.asarray(xy)).all(axis=1))[0])


def _rir(scene, rows, xy, heading, config=CONFIG) -> np.ndarray:
    return assemble(rows[[_node(scene, xy)]], np.array([heading]), config)[0].astype(np.float64)


def _onset(rir: np.ndarray) -> int:
    """First sample where either ear reaches 20 % of the response's peak."""
    envelope = np.abs(rir).max(axis=0)
    return int(np.argmax(envelope >= 0.2 * envelope.max()))


def test_config_validation():
    with pytest.raises(ConfigError, match="rir_length"):
        AcousticsConfig(rir_length=0)
    with pytest.raises(ConfigError, match="storage_dtype"):
        AcousticsConfig(storage_dtype="int8")
    with pytest.raises(ConfigError, match="early_length"):
        AcousticsConfig(early_length=1.0, rir_length=0.5)
    with pytest.raises(ConfigError, match="scattering"):
        AcousticsConfig(scattering=1.5)
    assert AcousticsConfig().digest() != AcousticsConfig(ism_max_order=2).digest()


def test_rows_shape_dtype(two_rooms):
    scene, rows = two_rooms
    assert rows.shape == (len(scene.grid.positions), CONFIG.row_length)
    assert rows.dtype == np.dtype(CONFIG.storage_dtype)
    assert np.isfinite(rows.astype(np.float32)).all()


@pytest.mark.parametrize("receiver_xy", [(0.5, 0.5), (2.5, 0.5), (3.5, 0.5)])
def test_direct_path_delay_is_distance_over_c(two_rooms, receiver_xy):
    scene, rows = two_rooms
    rir = _rir(scene, rows, receiver_xy, heading=0)  # facing +x: the source is straight ahead
    distance = np.hypot(SOURCE_XY[0] - receiver_xy[0], SOURCE_XY[1] - receiver_xy[1])
    assert abs(_onset(rir) - distance / C * FS) <= 2


def test_left_source_is_louder_and_earlier_in_left_ear(two_rooms):
    scene, rows = two_rooms
    # Receiver at (4.5, 2.5) facing -x (heading 2): the source at (4.5, 0.5) is on its left.
    rir = _rir(scene, rows, (4.5, 2.5), heading=2)
    start = _onset(rir)
    direct = rir[:, start - 4: start + 40]  # direct sound only, before the first reflection
    ild = 10 * np.log10((direct[0] ** 2).sum() / (direct[1] ** 2).sum())
    xcorr = np.correlate(np.repeat(direct[1], 8), np.repeat(direct[0], 8), mode="full")
    itd = (np.argmax(xcorr) - (8 * direct.shape[1] - 1)) / (8 * FS)
    assert ild > 3.0
    assert 0.3e-3 < itd < 0.85e-3
    mirrored = _rir(scene, rows, (4.5, 2.5), heading=0)  # facing +x: the source is on the right
    mirrored_direct = mirrored[:, start - 4: start + 40]
    assert (mirrored_direct[1] ** 2).sum() > 2 * (mirrored_direct[0] ** 2).sum()


def test_headings_change_early_part_only(two_rooms):
    scene, rows = two_rooms
    rirs = [_rir(scene, rows, (1.5, 2.5), heading=h) for h in range(4)]
    assert not np.allclose(rirs[0][:, :CONFIG.n_early], rirs[1][:, :CONFIG.n_early])
    assert np.array_equal(rirs[0][:, CONFIG.n_early:], rirs[2][:, CONFIG.n_early:])


def test_rt60_matches_eyring():
    # Absorption spread evenly over all surfaces: the diffuse field that Eyring's formula assumes
    # (a reflective room with one absorbing floor decays more slowly than Eyring predicts).
    labels = np.zeros((6, 4), dtype=int)
    scene = build_scene(labels, surfaces=[("wooden_lining", "carpet_thin", "ceiling_plasterboard", (1.0, 0.0, 0.0))])
    config = AcousticsConfig(n_rays=500)
    rows = simulate_source(scene, _node(scene, SOURCE_XY), config)
    expected = room_rt60(scene, 0, formula="eyring")
    assert expected.shape == BAND_CENTRES.shape
    for receiver in [(0.5, 3.5), (1.5, 0.5)]:
        rir = _rir(scene, rows, receiver, heading=1, config=config)
        for band in (2, 3, 4):  # 500 Hz, 1 kHz, 2 kHz octaves
            for ear in (0, 1):
                measured = measure_rt60(octave_band(rir[ear], BAND_CENTRES[band], FS), FS, decay_db=20)
                assert measured == pytest.approx(expected[band], rel=0.3), (receiver, band, ear)


def test_direct_energy_falls_with_distance(two_rooms):
    scene, rows = two_rooms
    energies = []
    for x in (3.5, 2.5, 1.5, 0.5):
        rir = _rir(scene, rows, (x, 0.5), heading=0)
        start = _onset(rir)
        energies.append((rir[:, start - 4: start + 16] ** 2).sum())
    assert all(a > b for a, b in zip(energies, energies[1:]))
    # 1 m vs 4 m: about 1/r^2 (12 dB), with a margin for the floor reflection and the tail onset.
    assert 8.0 < 10 * np.log10(energies[0] / energies[-1]) < 16.0


def test_wall_between_rooms_attenuates(two_rooms):
    scene, rows = two_rooms
    # The first 0.1 s: direct sound and early reflections. The late diffuse field of two rooms
    # coupled by a door is nearly the same on both sides, and a 1 s RIR holds much of it.
    early = slice(0, CONFIG.n_early)
    same_room = _rir(scene, rows, (0.5, 0.5), heading=0)[:, early]  # 4 m away, same room
    behind_wall = _rir(scene, rows, (8.5, 0.5), heading=0)[:, early]  # 4 m away, behind the wall at x = 6
    level = 10 * np.log10((behind_wall**2).sum() / (same_room**2).sum())
    assert level < -6.0, level


def test_sound_reaches_the_other_room_through_the_door():
    labels = np.zeros((10, 4), dtype=int)
    labels[6:] = 1
    scene = build_scene(labels, doors=[((5, 3), (6, 3))], surfaces=SURFACES)
    opaque = AcousticsConfig(n_rays=300, wall_transmission_db=float("inf"))
    rows = simulate_source(scene, _node(scene, (5.5, 2.5)), opaque)
    # (8.5, 3.5) sees the source through the door gap; (8.5, 0.5) only by reflections.
    through_door = _rir(scene, rows, (8.5, 3.5), heading=0, config=opaque)
    around = _rir(scene, rows, (8.5, 0.5), heading=0, config=opaque)
    assert (through_door**2).sum() > 0 and (around**2).sum() > 0
    direct_delay = int(np.hypot(3.0, 1.0) / C * FS)
    assert np.abs(through_door[:, direct_delay - 4: direct_delay + 8]).max() > 0.3 * np.abs(through_door).max()


def test_render_binaural_is_causal_full_convolution_prefix():
    rng = np.random.default_rng(0)
    clips = rng.standard_normal((3, 1000)).astype(np.float32)
    rirs = rng.standard_normal((3, 2, 300)).astype(np.float32)
    out = render_binaural(clips, rirs)
    assert out.shape == (3, 2, 1000) and out.dtype == np.float32
    expected = np.stack([[fftconvolve(clips[b], rirs[b, e])[:1000] for e in range(2)] for b in range(3)])
    assert np.allclose(out, expected, atol=1e-4)
    with pytest.raises(ConfigError):
        render_binaural(clips, rirs[:2])


def test_mix_is_mean_of_renders():
    renders = np.arange(2 * 3 * 2 * 5, dtype=np.float32).reshape(2, 3, 2, 5)
    assert np.allclose(mix(renders), (renders[0] + renders[1]) / 2)
    with pytest.raises(ConfigError):
        mix(renders[0])
