"""Audio-file reading and the seed's clip rule: 1 s windows louder than their file, power-normalised."""

from __future__ import annotations

from math import gcd
from pathlib import Path

import numpy as np

from m2h_ros.errors import AudioError, ConfigError

AUDIO_SUFFIXES = (".wav", ".flac", ".ogg")
# A window counts as above its file's mean power unless it is more than 0.1 % below it: without this
# slack a stationary sound (a steady hum, constant rain) would have no window "above" its own mean.
POWER_TOLERANCE = 1e-3


def resample(audio: np.ndarray, rate_in: int, rate_out: int) -> np.ndarray:
    """Polyphase resampling (scipy.signal.resample_poly) along the last axis."""
    if rate_in == rate_out:
        return audio
    from scipy.signal import resample_poly  # noqa: PLC0415

    divisor = gcd(rate_in, rate_out)
    return resample_poly(audio, rate_out // divisor, rate_in // divisor, axis=-1)


def read_audio_file(path: Path, *, sample_rate: int) -> np.ndarray:
    """Read a wav/flac/ogg file as mono float64 at ``sample_rate``: channels are averaged (downmix)."""
    import soundfile  # noqa: PLC0415

    try:
        data, rate = soundfile.read(str(path), dtype="float64", always_2d=True)
    except (RuntimeError, soundfile.LibsndfileError) as error:
        raise AudioError(f"cannot read audio file {path}: {error}") from error
    if data.size == 0:
        raise AudioError(f"audio file {path} holds no samples")
    if not np.isfinite(data).all():
        raise AudioError(f"audio file {path} holds NaN or infinite samples")
    return resample(data.mean(axis=1), rate, sample_rate)


def loud_offsets(audio: np.ndarray, *, clip_len: int, hop: int) -> np.ndarray:
    """Start samples (multiples of ``hop``) of the windows whose mean power is above the file's (see POWER_TOLERANCE)."""
    if audio.ndim != 1:
        raise AudioError(f"expected mono audio, got shape {audio.shape}")
    if len(audio) < clip_len:
        return np.zeros(0, dtype=np.int64)
    energy = np.concatenate(([0.0], np.cumsum(np.square(audio, dtype=np.float64))))
    starts = np.arange(0, len(audio) - clip_len + 1, hop, dtype=np.int64)
    window_power = (energy[starts + clip_len] - energy[starts]) / clip_len
    file_power = energy[-1] / len(audio)
    return starts[(window_power >= (1.0 - POWER_TOLERANCE) * file_power) & (window_power > 0.0)]


def spread_picks(candidates: list[np.ndarray], n: int, *, stride: int, hop: int,
                 rng: np.random.Generator) -> list[tuple[int, int]]:
    """Choose ``n`` (file index, start sample) pairs spread over the files round-robin.

    Within a file, starts on one randomly phased lattice of ``stride`` hops (clips that do not
    overlap) come first in random order, then the overlapping rest; then rank r of every file is
    taken before rank r + 1 of any. Raises ConfigError when fewer than ``n`` candidates exist.
    """
    files, ranks, starts = [], [], []
    for index, offsets in enumerate(candidates):
        count = len(offsets)
        if count == 0:
            continue
        overlapping = (offsets // hop - rng.integers(stride)) % stride != 0
        order = np.lexsort((rng.random(count), overlapping))
        rank = np.empty(count, dtype=np.int64)
        rank[order] = np.arange(count)
        files.append(np.full(count, index))
        ranks.append(rank)
        starts.append(offsets)
    total = sum(len(r) for r in ranks)
    if total < n:
        raise ConfigError(f"only {total} loud clip positions available, {n} asked for")
    file_of, rank_of, start_of = (np.concatenate(a) for a in (files, ranks, starts))
    chosen = np.lexsort((file_of, rank_of))[:n]
    chosen = chosen[np.lexsort((start_of[chosen], file_of[chosen]))]  # file order keeps loading cheap
    return [(int(file_of[i]), int(start_of[i])) for i in chosen]


def clip_power(clips: np.ndarray) -> np.ndarray:
    """Mean power of each clip (rows)."""
    return np.mean(np.square(clips, dtype=np.float64), axis=-1)


def normalise_power(clips: np.ndarray, *, target: float, mode: str) -> tuple[np.ndarray, np.ndarray]:
    """Scale clips to average power ``target``; returns (float32 clips, gain of each clip).

    ``mode="dataset"``: one gain for all clips, so that the mean clip power over the dataset is
    ``target`` (the seed's rule; relative loudness between clips is kept). ``mode="clip"``: every
    clip gets power ``target`` on its own.
    """
    power = clip_power(clips)
    if np.any(power <= 0.0):
        raise AudioError(f"{int(np.sum(power <= 0.0))} silent clips cannot be power-normalised")
    if mode == "dataset":
        gains = np.full(len(clips), np.sqrt(target / power.mean()))
    elif mode == "clip":
        gains = np.sqrt(target / power)
    else:
        raise ConfigError(f"normalisation must be 'dataset' or 'clip', got {mode!r}")
    return (clips * gains[:, None]).astype(np.float32), gains
