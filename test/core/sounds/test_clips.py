"""The clip rule on synthetic signals: loud windows, spread picks, power normalisation, file reading."""

import numpy as np
import pytest
import soundfile

from m2h_ros.core.sounds.clips import loud_offsets, normalise_power, read_audio_file, resample, spread_picks
from m2h_ros.errors import AudioError, ConfigError


def test_loud_offsets_keep_only_windows_above_the_file_mean():
    audio = np.zeros(64000)
    audio[40000:56000] = 1.0  # one loud second in four
    offsets = loud_offsets(audio, clip_len=16000, hop=4000)
    assert offsets.tolist() == [28000, 32000, 36000, 40000, 44000, 48000]  # >= 1/4 s of the burst
    power = np.array([np.mean(audio[o:o + 16000] ** 2) for o in offsets])
    assert (power >= np.mean(audio ** 2)).all()
    assert loud_offsets(np.ones(8000), clip_len=16000, hop=4000).size == 0  # shorter than a clip
    assert loud_offsets(np.zeros(32000), clip_len=16000, hop=4000).size == 0  # silence is never loud


def test_spread_picks_take_non_overlapping_clips_first_and_round_robin_over_files():
    hop, stride = 4000, 4
    candidates = [np.arange(0, 20 * hop, hop), np.arange(0, 3 * hop, hop), np.zeros(0, dtype=np.int64)]
    picks = spread_picks(candidates, 6, stride=stride, hop=hop, rng=np.random.default_rng(0))
    by_file = {f: sorted(s for g, s in picks if g == f) for f in (0, 1)}
    assert len(by_file[1]) == 3  # the short file gives all it has before file 0 gives a 4th...
    assert len(by_file[0]) == 3
    assert np.diff(by_file[0]).min() >= stride * hop  # ...and file 0's picks do not overlap
    again = spread_picks(candidates, 6, stride=stride, hop=hop, rng=np.random.default_rng(0))
    assert again == picks
    with pytest.raises(ConfigError, match="only 23 loud clip positions"):
        spread_picks(candidates, 24, stride=stride, hop=hop, rng=np.random.default_rng(0))


def test_normalise_power_over_the_dataset_or_per_clip():
    clips = np.stack([np.full(100, 1.0), np.full(100, 3.0)])
    dataset, gains = normalise_power(clips, target=1.2, mode="dataset")
    assert np.mean(dataset.astype(np.float64) ** 2) == pytest.approx(1.2)
    assert gains[0] == gains[1] and dataset.dtype == np.float32
    per_clip, _ = normalise_power(clips, target=1.2, mode="clip")
    np.testing.assert_allclose(np.mean(per_clip.astype(np.float64) ** 2, axis=1), [1.2, 1.2], rtol=1e-6)
    with pytest.raises(AudioError, match="silent"):
        normalise_power(np.zeros((2, 10)), target=1.2, mode="dataset")


def test_read_audio_file_downmixes_resamples_and_rejects_nan(tmp_path):
    t = np.arange(8000) / 8000
    tone = 0.5 * np.sin(2 * np.pi * 440 * t)
    soundfile.write(tmp_path / "stereo.flac", np.stack([tone, np.zeros_like(tone)], axis=1), 8000)
    audio = read_audio_file(tmp_path / "stereo.flac", sample_rate=16000)
    assert audio.shape == (16000,)
    spectrum = np.abs(np.fft.rfft(audio))
    assert np.argmax(spectrum) == 440  # 1 Hz bins: the tone kept its pitch
    assert np.sqrt(np.mean(audio[1000:-1000] ** 2)) == pytest.approx(0.25 / np.sqrt(2), rel=0.02)  # mean of L, R
    bad = tone.astype(np.float32)
    bad[100] = np.nan
    soundfile.write(tmp_path / "nan.wav", bad, 8000, subtype="FLOAT")
    with pytest.raises(AudioError, match="NaN"):
        read_audio_file(tmp_path / "nan.wav", sample_rate=16000)
    (tmp_path / "junk.wav").write_bytes(b"not audio")
    with pytest.raises(AudioError, match="cannot read"):
        read_audio_file(tmp_path / "junk.wav", sample_rate=16000)
    assert resample(tone, 8000, 8000) is tone
