"""Heads other than KEMAR: free-field pairs, SOFA files written by sofar, every bad SOFA case, and KEMAR
left exactly as it was (its banks keep their digest)."""

import hashlib
import shutil
import subprocess
import sys
import warnings

import numpy as np
import pytest
import sofar

from m2h_ros.core.world.acoustics import AcousticsConfig, simulate_source
from m2h_ros.core.world.scene import build_scene
from m2h_ros.core.world.hrtf import diffuse_field_power, load_head, parse_head, third_octave_smooth
from m2h_ros.errors import ConfigError, HeadError
from m2h_ros.node_configs import SimConfig
from m2h_ros.paths import REPO_DIR
from m2h_ros.sim_world import env_config

C = 343.0
# The KEMAR set as the simulation has always used it (16 kHz, equalised): hrirs, directions, weights,
# centre delay; and the bank digest every cached KEMAR bank is filed under.
KEMAR_SHA256 = "2d8ab42e61757dc75e468a65f48598ca1d1f7586fc3f0cb0d9b514fd87dbc999"
KEMAR_BANK_DIGEST = "10638cd03a526cd3"


def _itd_seconds(left: np.ndarray, right: np.ndarray, sample_rate: int, upsample: int = 16) -> float:
    """Lag (s) by which the right ear lags the left, from the upsampled cross-correlation peak."""
    n = (len(left) + len(right)) * upsample
    spec = np.fft.rfft(right, n // upsample) * np.conj(np.fft.rfft(left, n // upsample))
    xcorr = np.fft.irfft(spec, n)
    lag = int(np.argmax(xcorr))
    lag = lag - n if lag > n // 2 else lag
    return lag / (sample_rate * upsample)


def _ild_db(left: np.ndarray, right: np.ndarray, band=(200.0, 6000.0)) -> float:
    """Level difference (dB) of the ears in ``band`` (the resampling filter's edge left out)."""
    freqs = np.fft.rfftfreq(1024, 1 / 16000)
    inside = (freqs >= band[0]) & (freqs <= band[1])
    power = [(np.abs(np.fft.rfft(ear.astype(np.float64), 1024)) ** 2)[inside].sum() for ear in (left, right)]
    return float(10 * np.log10(power[0] / power[1]))


def _ears(hrtf, vector):
    index = int(hrtf.nearest(np.asarray(vector, dtype=np.float64)))
    return hrtf.directions[index], hrtf.hrirs[index].astype(np.float64)


# ----------------------------------------------------------------------------- free-field pair


@pytest.mark.parametrize("spacing", [0.1, 0.2, 0.4])
def test_free_field_itd_and_ild_match_the_pair_geometry(spacing):
    hrtf = load_head(f"free_field:{spacing}")
    assert hrtf.ear_spacing == spacing
    for azimuth in (-90, -45, 0, 30, 60, 90, 135, 180):
        direction, (left, right) = _ears(hrtf, [np.cos(np.deg2rad(azimuth)), np.sin(np.deg2rad(azimuth)), 0.0])
        # Left ear at +y: a source at direction u reaches it spacing/2 * u_y / c early, the right ear as late.
        expected = spacing * direction[1] / C
        assert _itd_seconds(left, right, 16000) == pytest.approx(expected, abs=0.04e-3), azimuth
        assert abs(_ild_db(left, right)) < 0.3, azimuth  # no head: no shadow


def test_free_field_pair_is_equalised_and_normalised_like_kemar():
    hrtf = load_head("free_field:0.2")
    assert hrtf.weights.sum() == pytest.approx(1.0) and (hrtf.weights > 0).all()
    energy = np.einsum("d,de->", hrtf.weights, (hrtf.hrirs.astype(np.float64) ** 2).sum(-1)) / 2
    assert energy == pytest.approx(1.0, rel=1e-3)
    freqs = np.fft.rfftfreq(1024, 1 / 16000)
    power = third_octave_smooth(diffuse_field_power(hrtf.hrirs, hrtf.weights, 1024), freqs)
    band = 10 * np.log10(power[(freqs >= 200) & (freqs <= 6000)])
    assert band.max() - band.min() < 1.0


@pytest.mark.parametrize("spec", ["free_field", "free_field:", "free_field:abc", "free_field:0", "free_field:3",
                                  "sofa:", "KEMAR", "sphere", ""])
def test_a_malformed_head_setting_is_a_config_error(spec):
    with pytest.raises(ConfigError, match="head"):
        parse_head(spec)
    with pytest.raises(ConfigError, match="head"):
        AcousticsConfig(head=spec)


# ----------------------------------------------------------------------------- SOFA files


def _grid():
    return np.array([(az, el, 1.5) for el in (-30, 0, 30, 60) for az in range(0, 360, 15)] + [(0, 90, 1.5)], float)


def _sofa(positions=None, *, receivers=2, rate=48000, length=128, itd_s=None, ild_db=6.0):
    """A SimpleFreeFieldHRIR (GeneralFIR for receivers != 2) whose ears are impulses: the left ear
    ``itd_s`` * sin(azimuth) cos(elevation) early and ild_db louder for left sources."""
    positions = _grid() if positions is None else positions
    az, el = np.deg2rad(positions[:, 0]), np.deg2rad(positions[:, 1])
    lateral = np.sin(az) * np.cos(el)
    itd_s = 0.5e-3 if itd_s is None else itd_s
    irs = np.zeros((len(positions), receivers, length))
    centre = length // 2
    for m, y in enumerate(lateral):
        for r in range(receivers):
            sign = 1.0 if r == 0 else -1.0  # receiver 0: left
            irs[m, r, int(round(centre - sign * y * itd_s / 2 * rate))] = 10 ** (sign * y * ild_db / 40)
    sofa = sofar.Sofa("SimpleFreeFieldHRIR" if receivers == 2 else "GeneralFIR")
    sofa.Data_IR = irs
    sofa.Data_Delay = np.zeros((1, receivers))
    sofa.Data_SamplingRate = float(rate)
    sofa.SourcePosition = positions
    sofa.ReceiverPosition = np.array([[[0.0], [0.08 - 0.16 * r / max(receivers - 1, 1)], [0.0]]
                                      for r in range(receivers)])
    return sofa


def _write(tmp_path, sofa, name="head.sofa"):
    path = tmp_path / name
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        sofar.write_sofa(str(path), sofa)
    return path


def test_a_sofa_file_written_by_sofar_round_trips(tmp_path):
    itd, ild = 0.6e-3, 8.0
    path = _write(tmp_path, _sofa(itd_s=itd, ild_db=ild))
    hrtf = load_head(f"sofa:{path}")
    grid = _grid()
    assert hrtf.hrirs.shape[:2] == (len(grid), 2) and hrtf.sample_rate == 16000  # 48 kHz resampled
    az, el = np.deg2rad(grid[:, 0]), np.deg2rad(grid[:, 1])
    assert np.allclose(hrtf.directions, np.stack([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)], 1))
    assert hrtf.ear_spacing == pytest.approx(0.16)
    for vector, lateral in (([0, 1, 0], 1.0), ([0, -1, 0], -1.0), ([1, 0, 0], 0.0), ([-1, 1, 0], np.sqrt(0.5))):
        direction, (left, right) = _ears(hrtf, vector)
        assert direction[1] == pytest.approx(lateral, abs=1e-6)
        # Same impulse pair in, same ITD and ILD out: equalisation is one filter on every ear.
        assert _itd_seconds(left, right, 16000) == pytest.approx(lateral * itd, abs=0.03e-3)
        assert _ild_db(left, right) == pytest.approx(lateral * ild, abs=0.3)


def test_cartesian_positions_give_the_same_head(tmp_path):
    spherical = _sofa()
    grid = _grid()
    az, el = np.deg2rad(grid[:, 0]), np.deg2rad(grid[:, 1])
    cartesian = _sofa()
    cartesian.SourcePosition = np.stack([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)], 1) * 1.5
    cartesian.SourcePosition_Type, cartesian.SourcePosition_Units = "cartesian", "metre"
    a = load_head(f"sofa:{_write(tmp_path, spherical, 'a.sofa')}")
    b = load_head(f"sofa:{_write(tmp_path, cartesian, 'b.sofa')}")
    assert np.allclose(a.directions, b.directions) and np.array_equal(a.hrirs, b.hrirs)


def test_the_spherical_head_script_writes_a_head_with_woodworths_itd(tmp_path):
    path = tmp_path / "sphere.sofa"
    subprocess.run([sys.executable, str(REPO_DIR / "scripts" / "write_head_sofa.py"), "--out", str(path)],
                   check=True, capture_output=True)
    hrtf = load_head(f"sofa:{path}")
    _, (left, right) = _ears(hrtf, [0, 1, 0])
    radius = 0.0875
    assert _itd_seconds(left, right, 16000) == pytest.approx(radius / C * (1 + np.pi / 2), abs=0.05e-3)
    assert _ild_db(left, right) > 5  # the sphere shadows the far ear
    _, (front_left, front_right) = _ears(hrtf, [1, 0, 0])
    assert abs(_itd_seconds(front_left, front_right, 16000)) < 0.03e-3
    assert abs(_ild_db(front_left, front_right)) < 0.1


def _bad(tmp_path, **change):
    sofa = _sofa()
    for name, value in change.items():
        setattr(sofa, name, value)
    return f"sofa:{_write(tmp_path, sofa)}"


def test_each_bad_sofa_file_is_a_head_error_naming_the_problem(tmp_path):
    ir = _sofa().Data_IR
    grid = _grid()
    nan, inf, silent_ear = ir.copy(), ir.copy(), ir.copy()
    nan[3, 0, 5] = np.nan
    inf[4, 1, 0] = np.inf
    silent_ear[:, 1] = 0.0
    one_zero = ir.copy()
    one_zero[7] = 0.0
    high = grid.copy()
    high[2, 1] = 120.0
    garbage = tmp_path / "garbage.sofa"
    garbage.write_bytes(b"not a SOFA file" * 100)
    transfer = sofar.Sofa("SimpleFreeFieldHRTF")
    cases = [
        ("does not exist", f"sofa:{tmp_path / 'missing.sofa'}"),
        ("unreadable as SOFA", f"sofa:{garbage}"),
        ("holds no impulse responses", f"sofa:{_write(tmp_path, transfer, 'tf.sofa')}"),
        ("has 1 receivers; a binaural head needs 2", f"sofa:{_write(tmp_path, _sofa(receivers=1), 'one.sofa')}"),
        ("has 3 receivers; a binaural head needs 2", f"sofa:{_write(tmp_path, _sofa(receivers=3), 'three.sofa')}"),
        ("1 of 97 impulse responses hold NaN or infinite", _bad(tmp_path / "nan", Data_IR=nan)),
        ("1 of 97 impulse responses hold NaN or infinite", _bad(tmp_path / "inf", Data_IR=inf)),
        (r"97 of 97 directions have an all-zero impulse response \(right ear\)",
         _bad(tmp_path / "ear", Data_IR=silent_ear)),
        (r"1 of 97 directions have an all-zero impulse response \(left and right ear\)",
         _bad(tmp_path / "zero", Data_IR=one_zero)),
        (r"elevations outside \[-90, 90\] degrees \(e.g. 120\)", _bad(tmp_path / "el", SourcePosition=high)),
        ("source positions are at the head's centre",
         _bad(tmp_path / "origin", SourcePosition=np.zeros_like(grid), SourcePosition_Type="cartesian",
              SourcePosition_Units="metre")),
        ("every impulse response is at the same direction",
         _bad(tmp_path / "same", SourcePosition=np.tile([30.0, 0.0, 1.5], (len(grid), 1)))),
        ("sampled at 8000 Hz, below the simulation's 16000 Hz", f"sofa:{_write(tmp_path, _sofa(rate=8000), 'low.sofa')}"),
    ]
    for message, spec in cases:
        with pytest.raises(HeadError, match=message):
            load_head(spec)


@pytest.fixture(autouse=True)
def _dirs(tmp_path):
    for name in ("nan", "inf", "ear", "zero", "el", "origin", "same"):
        (tmp_path / name).mkdir()


def test_higher_rates_are_resampled_to_the_same_head(tmp_path):
    heads = [load_head(f"sofa:{_write(tmp_path, _sofa(rate=rate, length=length), f'{rate}.sofa')}")
             for rate, length in ((16000, 48), (48000, 144), (96000, 288))]
    for hrtf in heads:
        _, (left, right) = _ears(hrtf, [0, 1, 0])
        assert _itd_seconds(left, right, 16000) == pytest.approx(0.5e-3, abs=0.04e-3)
        assert _ild_db(left, right) == pytest.approx(6.0, abs=0.3)


# ----------------------------------------------------------------------------- keys and settings


def test_kemar_is_bit_identical_and_keeps_its_bank_digest():
    hrtf = load_head("kemar")
    digest = hashlib.sha256()
    for array in (hrtf.hrirs, hrtf.directions, hrtf.weights):
        digest.update(np.ascontiguousarray(array).tobytes())
    digest.update(repr(hrtf.centre_delay).encode())
    assert digest.hexdigest() == KEMAR_SHA256
    assert AcousticsConfig().digest() == KEMAR_BANK_DIGEST
    assert AcousticsConfig(head="kemar").digest() == KEMAR_BANK_DIGEST
    assert hrtf.ear_spacing is None  # the tail's coherence keeps using head_width


def test_banks_are_keyed_by_the_heads_content_not_its_path(tmp_path):
    path = _write(tmp_path, _sofa())
    copy = tmp_path / "copy" / "renamed.sofa"
    copy.parent.mkdir()
    shutil.copy(path, copy)
    digests = {AcousticsConfig(head=f"sofa:{p}").digest() for p in (path, copy)}
    assert len(digests) == 1 and KEMAR_BANK_DIGEST not in digests
    other = _sofa(itd_s=0.4e-3)
    changed = AcousticsConfig(head=f"sofa:{_write(tmp_path, other, 'other.sofa')}").digest()
    assert changed not in digests
    pairs = {AcousticsConfig(head=f"free_field:{s}").digest() for s in (0.1, 0.2)}
    assert len(pairs) == 2 and not pairs & (digests | {KEMAR_BANK_DIGEST})


def _direct_sound_by_heading(head: str):
    """(4, 2, E) early responses of a source 3 m along +x of the receiver (direct sound only), per heading."""
    labels = np.zeros((6, 3), dtype=int)
    scene = build_scene(labels, doors=[], surfaces=[("plasterboard", "carpet_cotton", "ceiling_plasterboard",
                                                     (1.0, 0.0, 0.0))])
    node = {tuple(xy): n for n, xy in enumerate(scene.grid.positions.tolist())}
    config = AcousticsConfig(head=head, ism_max_order=0, tail=False, rir_length=0.25)
    rows = simulate_source(scene, node[(4.5, 1.5)], config)
    return rows[node[(1.5, 1.5)], : 4 * 2 * config.n_early].reshape(4, 2, config.n_early).astype(np.float64)


def test_the_room_is_heard_through_the_chosen_head():
    """The bank a scene is rendered into carries the chosen head's cues, heading by heading (heading h faces
    h x 90 degrees from +x; the source lies along +x): a free-field pair's delay of its spacing and no level
    difference; KEMAR's shorter delay and its head shadow. A renderer that ignored the setting fails."""
    spacing = 0.4
    pair, kemar = _direct_sound_by_heading(f"free_field:{spacing}"), _direct_sound_by_heading("kemar")
    # The right ear lags the left by (spacing / c) x the source's leftward component in the head frame.
    for heading, leftward in enumerate((0.0, -1.0, 0.0, 1.0)):
        left, right = pair[heading]
        assert _itd_seconds(left, right, 16000) == pytest.approx(spacing * leftward / C, abs=0.1e-3), heading
        assert abs(_ild_db(left, right)) < 0.5, heading
    for heading, side in ((1, -1.0), (3, 1.0)):  # the source at the right ear, then at the left
        left, right = kemar[heading]
        assert side * _itd_seconds(left, right, 16000) == pytest.approx(0.65e-3, abs=0.15e-3), heading
        assert side * _ild_db(left, right) > 5.0, heading  # the head shadows the far ear


def test_the_sim_setting_reaches_the_acoustics(tmp_path):
    assert env_config(SimConfig()).acoustics.head == "kemar"
    assert env_config(SimConfig(head="free_field:0.2", acoustics="fast")).acoustics.head == "free_field:0.2"
    with pytest.raises(ConfigError, match="head"):
        SimConfig(head="bogus")


def test_the_policy_training_command_hears_through_the_head():
    from m2h_ros.training.ppo_cli import build_parser, config_from_args

    def head(argv):
        return config_from_args(build_parser().parse_args(["--kind", "quality", *argv])).env.acoustics.head

    assert head(["--head", "sofa:robot.sofa"]) == "sofa:robot.sofa"
    assert head([]) == "kemar"


def test_the_training_command_renders_every_stream_through_the_head():
    from m2h_ros.training.pretrain_separator import build_parser, config_from_args

    def heads(argv):
        config = config_from_args(build_parser().parse_args(argv))
        return {stream.env.acoustics.head for stream in (config.train_data, config.refiner_data, config.val_data)}

    assert heads(["--head", "free_field:0.2"]) == {"free_field:0.2"}
    assert heads([]) == {"kemar"}
