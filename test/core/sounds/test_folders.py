"""SoundLibrary.from_folders on tiny generated folder trees: layout, resampling, loud windows, errors."""

from pathlib import Path

import numpy as np
import pytest
import soundfile

from m2h_ros.core.sounds.clips import POWER_TOLERANCE, clip_power
from m2h_ros.core.sounds.library import SoundLibrary, SoundLibraryConfig
from m2h_ros.errors import AudioError, ConfigError

CONFIG = SoundLibraryConfig(clips_heard=3, clips_unheard=2, seed=5)


def tone(freq: float, seconds: float, rate: int, *, quiet_first: float = 0.0) -> np.ndarray:
    """A tone whose first ``quiet_first`` seconds are 40 dB down (so only later windows are loud)."""
    t = np.arange(int(seconds * rate)) / rate
    audio = 0.3 * np.sin(2 * np.pi * freq * t)
    audio[t < quiet_first] *= 0.01
    return audio


def write(path: Path, audio: np.ndarray, rate: int) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    soundfile.write(path, audio.astype(np.float32), rate)


def make_tree(root: Path) -> Path:
    # speech/low: 8 kHz stereo wav and 22.05 kHz flac; music/high: 44.1 kHz ogg; background/hum.
    write(root / "speech/low/heard/a.wav", np.stack([tone(300, 4, 8000, quiet_first=2)] * 2, axis=1), 8000)
    write(root / "speech/low/heard/b.flac", tone(310, 3, 22050, quiet_first=1.5), 22050)
    write(root / "speech/low/unheard/c.wav", tone(320, 3, 8000, quiet_first=1.5), 8000)
    write(root / "music/high/heard/d.ogg", tone(1000, 4, 44100), 44100)
    write(root / "music/high/unheard/e.ogg", tone(1100, 3, 44100), 44100)
    write(root / "background/hum/heard/f.wav", tone(60, 3, 16000) * 0.1, 16000)
    write(root / "background/hum/unheard/g.wav", tone(70, 3, 16000) * 0.1, 16000)
    return root


def test_from_folders_builds_a_library_from_the_layout(tmp_path):
    library = SoundLibrary.from_folders(make_tree(tmp_path), config=CONFIG)
    assert library.categories == ("speech", "music", "background")
    assert library.classes == ("low", "high", "hum")
    assert library.path is None
    for split in ("heard", "unheard"):
        clips = library.clips(split)
        assert clips.shape == (3 * CONFIG.clips_per_class(split), 16000) and clips.dtype == np.float32
    everything = np.concatenate([library.clips("heard"), library.clips("unheard")])
    assert np.mean(clip_power(everything)) == pytest.approx(1.2, rel=1e-4)
    # Only the loud second halves of the speech files qualify as clips.
    for info in library.infos("heard", cls="low") + library.infos("unheard", cls="low"):
        quiet = 2.0 if info.source_file.endswith("a.wav") else 1.5
        assert info.offset_s >= quiet - 0.5  # at most half of a clip may be quiet (then it is at the mean)
        assert info.raw_power >= (1 - POWER_TOLERANCE) * info.file_power
    # Resampled tones keep their pitch: the 44.1 kHz ogg's 1 kHz tone peaks at bin 1000 of 1 s.
    spectrum = np.abs(np.fft.rfft(library.clips("heard", cls="high")[0]))
    assert np.argmax(spectrum) == 1000
    heard = {i.source_file for i in library.infos("heard")}
    assert not heard & {i.source_file for i in library.infos("unheard")}
    assert {i.package for i in library.infos("heard")} == {"user folder"}


def test_from_folders_is_deterministic_per_seed(tmp_path):
    root = make_tree(tmp_path)
    first, second = (SoundLibrary.from_folders(root, config=CONFIG) for _ in range(2))
    np.testing.assert_array_equal(first.clips("heard"), second.clips("heard"))
    assert first.fingerprint == second.fingerprint != CONFIG.fingerprint()
    write(root / "music/high/heard/d.ogg", tone(1200, 4, 44100), 44100)  # new content, new fingerprint
    assert SoundLibrary.from_folders(root, config=CONFIG).fingerprint != first.fingerprint
    other = SoundLibrary.from_folders(root, config=SoundLibraryConfig(clips_heard=3, clips_unheard=2, seed=6))
    assert ([i.offset_s for i in other.infos("heard", cls="high")]
            != [i.offset_s for i in first.infos("heard", cls="high")])


def test_from_folders_errors_name_the_problem(tmp_path):
    root = make_tree(tmp_path / "unknown")
    write(root / "noise/white/heard/x.wav", tone(50, 2, 16000), 16000)
    with pytest.raises(ConfigError, match="unknown sound category folder .*noise"):
        SoundLibrary.from_folders(root, config=CONFIG)

    root = make_tree(tmp_path / "empty")
    (root / "music/empty/heard").mkdir(parents=True)
    write(root / "music/empty/unheard/y.wav", tone(50, 2, 16000), 16000)
    with pytest.raises(AudioError, match="empty has no audio files in heard/"):
        SoundLibrary.from_folders(root, config=CONFIG)

    root = make_tree(tmp_path / "nan")
    bad = tone(200, 2, 16000)
    bad[5] = np.nan
    soundfile.write(root / "speech/low/heard/bad.wav", bad.astype(np.float32), 16000, subtype="FLOAT")
    with pytest.raises(AudioError, match="bad.wav holds NaN"):
        SoundLibrary.from_folders(root, config=CONFIG)

    root = make_tree(tmp_path / "shared")
    (root / "music/high/unheard/copy.ogg").write_bytes((root / "music/high/heard/d.ogg").read_bytes())
    with pytest.raises(ConfigError, match="heard and unheard must not share"):
        SoundLibrary.from_folders(root, config=CONFIG)

    root = make_tree(tmp_path / "scarce")
    with pytest.raises(ConfigError, match="class 'low' \\(heard, 2 files\\): only"):
        SoundLibrary.from_folders(root, config=SoundLibraryConfig(clips_heard=40, clips_unheard=2))

    with pytest.raises(ConfigError, match="not a directory"):
        SoundLibrary.from_folders(tmp_path / "missing", config=CONFIG)
    (tmp_path / "bare").mkdir()
    with pytest.raises(ConfigError, match="no <category>/<class>/ folders"):
        SoundLibrary.from_folders(tmp_path / "bare", config=CONFIG)
