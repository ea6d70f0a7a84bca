"""The shipped default separator loads, rebuilds itself and separates a recording of real clips."""

import numpy as np
import scipy.signal
import soundfile
from known_mixture import SEPARATION_FLOOR_DB

from m2h_ros.core.audio.metrics import si_sdr
from m2h_ros.models.checkpoint import DEFAULT_SEPARATOR_CHECKPOINT, load_separator
from m2h_ros.separate_cli import main


def test_default_checkpoint_loads_with_its_settings():
    loaded = load_separator(DEFAULT_SEPARATOR_CHECKPOINT)
    assert DEFAULT_SEPARATOR_CHECKPOINT.stat().st_size < 10_000_000
    assert set(loaded.classes) == {"speech", "music"}
    assert (loaded.stft.n_fft, loaded.stft.hop_length, loaded.stft.n_freq) == (1023, 512, 512)


def test_m2h_separate_with_the_default_checkpoint(tmp_path, speech_under_music):
    mixture, reference = speech_under_music
    rate = 44100  # written at a rate other than the separator's: the file is resampled both ways
    stereo = scipy.signal.resample_poly(mixture, 441, 160, axis=0).astype(np.float32)
    soundfile.write(tmp_path / "in.wav", stereo, rate, subtype="FLOAT")
    assert main([str(tmp_path / "in.wav"), str(tmp_path / "out.wav"), "--target", "speech"]) == 0
    out, out_rate = soundfile.read(tmp_path / "out.wav")
    assert out_rate == rate and out.ndim == 1 and len(out) == len(stereo)
    estimate = scipy.signal.resample_poly(out, 160, 441)[: len(reference)]
    gain = si_sdr(estimate, reference) - si_sdr(mixture.mean(axis=1), reference)
    assert gain > SEPARATION_FLOOR_DB, f"{gain:+.2f} dB over the mixture"
