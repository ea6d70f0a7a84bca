"""Spectrograms as pictures to look at."""

import numpy as np

from m2h_ros.core.audio.display import BINS_PER_ROW, FLOOR_DB, spectrogram_image
from m2h_ros.core.audio.stft import DEFAULT_STFT, stft


def test_the_spectrogram_picture_has_high_frequencies_on_top():
    t = np.arange(DEFAULT_STFT.clip_samples) / DEFAULT_STFT.sample_rate
    tone = np.sin(2 * np.pi * 6000 * t).astype(np.float32)
    picture = spectrogram_image(np.abs(stft(np.stack([tone, tone]), config=DEFAULT_STFT)))
    assert picture.shape == (DEFAULT_STFT.n_freq // BINS_PER_ROW, DEFAULT_STFT.n_frames) and picture.dtype == np.float32
    loudest = int(np.argmax(picture[:, 10]))
    hz_per_row = DEFAULT_STFT.sample_rate / 2 / picture.shape[0]
    assert abs((picture.shape[0] - 1 - loudest) * hz_per_row - 6000) < 2 * hz_per_row
    assert picture.min() >= FLOOR_DB
