"""The shipped default separator loads, rebuilds itself and separates a real-length recording."""

import numpy as np
import soundfile

from m2h_ros.models.checkpoint import DEFAULT_SEPARATOR_CHECKPOINT, load_separator
from m2h_ros.separate_cli import main


def test_default_checkpoint_loads_with_its_settings():
    loaded = load_separator(DEFAULT_SEPARATOR_CHECKPOINT)
    assert DEFAULT_SEPARATOR_CHECKPOINT.stat().st_size < 10_000_000
    assert set(loaded.classes) == {"speech", "music"}
    assert (loaded.stft.n_fft, loaded.stft.hop_length, loaded.stft.n_freq) == (1023, 512, 512)


def test_m2h_separate_with_the_default_checkpoint(tmp_path):
    rate = 44100
    t = np.arange(int(2.5 * rate)) / rate
    voice = np.sin(2 * np.pi * 220 * t) * (1 + np.sin(2 * np.pi * 3 * t)) * 0.3
    noise = np.random.default_rng(0).standard_normal(t.size) * 0.05
    stereo = np.stack([voice + noise, 0.8 * voice + noise], axis=1).astype(np.float32)
    soundfile.write(tmp_path / "in.wav", stereo, rate)
    assert main([str(tmp_path / "in.wav"), str(tmp_path / "out.wav"), "--target", "speech"]) == 0
    out, out_rate = soundfile.read(tmp_path / "out.wav")
    assert out_rate == rate and out.ndim == 1 and len(out) == len(stereo)
    assert np.isfinite(out).all() and np.abs(out).max() > 0
