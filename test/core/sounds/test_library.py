"""The built-in library (small build from the real Debian / music21 material) and its disk cache."""

import json
import re
from pathlib import Path

import numpy as np
import pytest

from m2h_ros.core.sounds.clips import POWER_TOLERANCE, clip_power
from m2h_ros.core.sounds.library import CATEGORIES, SPLITS, SoundLibrary, SoundLibraryConfig
from m2h_ros.core.sounds.sources import CLASS_SPECS, DEBIAN_PACKAGES, list_sources, load_source
from m2h_ros.core.world.hrtf import HRTF_PACKAGE
from m2h_ros.errors import CacheError, ConfigError

pytestmark = pytest.mark.slow  # builds the real --small library once per session

REPO = Path(__file__).resolve().parents[3]
SMALL = SoundLibraryConfig.small()


def test_clips_have_the_configured_length_dtype_and_counts(small_library):
    assert small_library.categories == CATEGORIES
    assert len(small_library.classes) == len(CLASS_SPECS)
    for split in SPLITS:
        clips = small_library.clips(split)
        assert clips.dtype == np.float32
        assert clips.shape == (len(CLASS_SPECS) * SMALL.clips_per_class(split), 16000)
        assert isinstance(clips, np.memmap)  # memory-mapped, not read into memory
        assert np.isfinite(clips).all()
        for cls in small_library.classes:
            assert small_library.clips(split, cls=cls).shape == (SMALL.clips_per_class(split), 16000)
            assert {i.cls for i in small_library.infos(split, cls=cls)} == {cls}
    speech = small_library.clips("heard", category="speech")
    assert len(speech) == 5 * SMALL.clips_heard
    assert [i.category for i in small_library.infos("heard", category="speech")] == ["speech"] * len(speech)


def test_power_is_normalised_to_1_2_over_the_dataset(small_library):
    everything = np.concatenate([small_library.clips(split) for split in SPLITS])
    assert np.mean(clip_power(everything)) == pytest.approx(1.2, rel=1e-4)
    gains = {info.gain for split in SPLITS for info in small_library.infos(split)}
    assert len(gains) == 1  # one gain for the whole dataset: relative loudness is kept
    powers = clip_power(everything)
    assert powers.max() / powers.min() > 2.0


def test_every_clip_is_louder_than_its_source_file(small_library, sound_sources):
    for split in SPLITS:
        assert all(i.raw_power >= (1 - POWER_TOLERANCE) * i.file_power > 0.0 for i in small_library.infos(split))
    # Recompute from the decoded sources for one clip of each kind of source.
    checked_kinds = set()
    specs = {spec.name: spec for spec in CLASS_SPECS}
    for info in small_library.infos("unheard"):
        spec = specs[info.cls]
        if spec.kind in checked_kinds:
            continue
        checked_kinds.add(spec.kind)
        source = next(s for s in list_sources(spec, sound_sources, min_seconds=1.0, music_seconds=SMALL.music_seconds)
                      if s.path == info.source_file)
        audio = load_source(source, sound_sources, sample_rate=16000)
        start = int(round(info.offset_s * 16000))
        window = audio[start:start + 16000]
        assert np.mean(window ** 2) == pytest.approx(info.raw_power, rel=1e-5)
        assert np.mean(window ** 2) >= (1 - POWER_TOLERANCE) * np.mean(audio ** 2)
        np.testing.assert_allclose(small_library.clip(info.clip_id), window * info.gain, rtol=1e-4, atol=1e-6)
    assert checked_kinds == {"g722", "music21", "audio_file"}


def test_heard_and_unheard_never_share_a_source_file(small_library):
    manifest = json.loads((small_library.path / "manifest.json").read_text())
    for entry in manifest["classes"]:
        assert entry["files"]["heard"] and entry["files"]["unheard"]
        assert not set(entry["files"]["heard"]) & set(entry["files"]["unheard"])
    for cls in small_library.classes:
        heard = {i.source_file for i in small_library.infos("heard", cls=cls)}
        unheard = {i.source_file for i in small_library.infos("unheard", cls=cls)}
        assert heard and unheard and not heard & unheard


def test_manifest_names_package_and_licence_of_every_clip(small_library):
    manifest = json.loads((small_library.path / "manifest.json").read_text())
    clips = manifest["clips"]
    assert len(clips) == sum(len(small_library.clips(split)) for split in SPLITS)
    assert len({c["clip_id"] for c in clips}) == len(clips)
    for clip in clips:
        assert clip["licence"] and clip["source_file"]
        package = clip["package"]
        if package.startswith("music21=="):
            assert f"timgm6mb-soundfont={DEBIAN_PACKAGES['timgm6mb-soundfont']}" in package
        else:
            name, version = package.split("=")
            assert DEBIAN_PACKAGES[name] == version
    assert manifest["config"]["seed"] == SMALL.seed and manifest["fingerprint"] == SMALL.fingerprint()


def test_clips_are_deterministic_per_seed_and_class(small_library, sound_sources, tmp_path, monkeypatch):
    """A library of two classes cut with the same seed holds exactly the same raw windows."""
    monkeypatch.setenv("M2H_DATA_DIR", str(tmp_path))
    pair = ("it_male", "traffic")
    subset = SoundLibrary.build(SoundLibraryConfig(**{**SMALL.__dict__, "classes": pair}),
                                sources=sound_sources, progress=False)
    assert subset.classes == pair
    for cls in pair:
        for split in SPLITS:
            ours, theirs = subset.infos(split, cls=cls), small_library.infos(split, cls=cls)
            assert [(i.source_file, i.offset_s) for i in ours] == [(i.source_file, i.offset_s) for i in theirs]
            np.testing.assert_allclose(subset.clips(split, cls=cls) / ours[0].gain,
                                       small_library.clips(split, cls=cls) / theirs[0].gain, rtol=1e-5, atol=1e-6)
    reseeded = SoundLibrary.build(SoundLibraryConfig(**{**SMALL.__dict__, "classes": pair, "seed": 7}),
                                  sources=sound_sources, progress=False)
    assert ([i.offset_s for i in reseeded.infos("heard", cls="it_male")]
            != [i.offset_s for i in subset.infos("heard", cls="it_male")])


def test_sample_is_deterministic_and_respects_category_and_split(small_library):
    draws = [small_library.sample(np.random.default_rng(3), category="music", split="unheard") for _ in range(2)]
    assert draws[0][1] == draws[1][1]
    np.testing.assert_array_equal(draws[0][0], draws[1][0])
    rng = np.random.default_rng(0)
    ids = [small_library.sample(rng, category="background", split="heard")[1] for _ in range(60)]
    infos = [small_library.info(i) for i in ids]
    assert {i.category for i in infos} == {"background"} and {i.split for i in infos} == {"heard"}
    assert len({i.cls for i in infos}) == 5  # classes drawn uniformly: all five appear in 60 draws
    clip, clip_id = small_library.sample(rng, category="speech", cls="ru_female")
    assert small_library.info(clip_id).cls == "ru_female"
    np.testing.assert_array_equal(clip, small_library.clip(clip_id))
    with pytest.raises(ConfigError, match="unknown sound category 'noise'"):
        small_library.sample(rng, category="noise")
    with pytest.raises(ConfigError, match="split must be one of"):
        small_library.sample(rng, category="speech", split="test")


def test_load_reopens_the_built_library_and_reports_missing_or_corrupt(small_library, small_data_dir,
                                                                       tmp_path, monkeypatch):
    monkeypatch.setenv("M2H_DATA_DIR", str(small_data_dir))
    reopened = SoundLibrary.load(SMALL)
    assert reopened.classes == small_library.classes
    np.testing.assert_array_equal(reopened.clips("unheard"), small_library.clips("unheard"))

    monkeypatch.setenv("M2H_DATA_DIR", str(tmp_path))
    with pytest.raises(CacheError, match=re.escape("scripts/build_sound_library.py --small")):
        SoundLibrary.load(SMALL)
    with pytest.raises(CacheError, match=re.escape("`python scripts/build_sound_library.py`")):
        SoundLibrary.load()
    corrupt = SoundLibrary.path_for(SMALL)
    corrupt.mkdir(parents=True)
    for name in ("heard.npy", "unheard.npy", "manifest.json"):
        (corrupt / name).write_bytes((small_library.path / name).read_bytes())
    (corrupt / "heard.npy").write_bytes((small_library.path / "heard.npy").read_bytes()[:5000])
    with pytest.raises(CacheError, match="corrupt.*build_sound_library.py --small"):
        SoundLibrary.load(SMALL)
    (corrupt / "manifest.json").write_text("{not json")
    with pytest.raises(CacheError, match="corrupt"):
        SoundLibrary.load(SMALL)


def test_too_many_clips_for_the_material_names_the_class(sound_sources, tmp_path, monkeypatch):
    monkeypatch.setenv("M2H_DATA_DIR", str(tmp_path))
    greedy = SoundLibraryConfig(clips_heard=400, clips_unheard=2, classes=("traffic",), max_files_per_class=4)
    with pytest.raises(ConfigError, match="class 'traffic' \\(heard"):
        SoundLibrary.build(greedy, sources=sound_sources, progress=False)
    assert not any(tmp_path.rglob("*.npy"))  # nothing half-written


def test_missing_sources_say_how_to_fetch(tmp_path):
    with pytest.raises(CacheError, match="fetch_sound_sources.sh"):
        SoundLibrary.build(SMALL, sources=tmp_path, progress=False)


@pytest.mark.parametrize("field, value", [("clips_heard", 0), ("normalisation", "peak"), ("unheard_fraction", 1.0),
                                          ("hop_seconds", 0.3), ("classes", ("en_female", "kazoo")),
                                          ("max_files_per_class", 1)])
def test_config_rejects_bad_values(field, value):
    with pytest.raises(ConfigError, match=field):
        SoundLibraryConfig(**{field: value})


def test_fetch_script_pins_the_same_packages():
    script = (REPO / "scripts" / "fetch_sound_sources.sh").read_text()
    pinned = dict(re.findall(r'^\s*"([a-z0-9.+-]+)=([^=]+)=[^"]*"', script, flags=re.M))
    # The fetch script also brings the HRTF (an acoustics input, not part of the library's key).
    assert pinned == {**DEBIAN_PACKAGES, HRTF_PACKAGE[0]: HRTF_PACKAGE[1]}
