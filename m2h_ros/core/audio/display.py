"""Spectrograms as pictures to look at (what a 32FC1 sensor_msgs/Image carries to an image panel)."""

from __future__ import annotations

import numpy as np

from m2h_ros.errors import AudioError

# A picture row is the mean magnitude of this many STFT bins (4 x 15.6 Hz = 62.5 Hz at 16 kHz): 128
# rows by 32 frames per 1 s step instead of 512 x 32, so an image panel shows it at a readable shape.
BINS_PER_ROW = 4
FLOOR_DB = -60.0  # magnitudes below this (dB re 1) are shown as this


def spectrogram_image(magnitude: np.ndarray) -> np.ndarray:
    """A linear STFT magnitude, (F, T) or (channels, F, T) (channels averaged), -> a (F / BINS_PER_ROW,
    T) float32 picture in dB, highest frequencies in the top row, at least FLOOR_DB."""
    magnitude = np.asarray(magnitude, np.float32)
    if magnitude.ndim == 3:
        magnitude = magnitude.mean(axis=0)
    if magnitude.ndim != 2 or magnitude.shape[0] % BINS_PER_ROW:
        raise AudioError(f"spectrogram_image needs (F, T) with F a multiple of {BINS_PER_ROW}, got {magnitude.shape}")
    bands = magnitude.reshape(-1, BINS_PER_ROW, magnitude.shape[1]).mean(axis=1)
    decibels = np.maximum(20 * np.log10(np.maximum(bands, 1e-12)), FLOOR_DB)
    return np.ascontiguousarray(decibels[::-1], np.float32)
