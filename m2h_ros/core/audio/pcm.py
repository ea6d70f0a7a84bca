"""Float audio as signed 16-bit PCM, the format players take (Foxglove's RawAudio ``pcm-s16``)."""

import numpy as np


def pcm_int16(samples: np.ndarray, *, gain: float) -> bytes:
    """``(channels, n)`` (or ``(n,)``) float samples times ``gain``, clipped to [-1, 1], as interleaved
    little-endian int16 frames.

    The simulator's audio is not in [-1, 1] (clips are normalised to an average power of 1.2, mixtures
    peak near 20): one fixed gain, not a per-frame one, keeps loudness comparable from step to step."""
    planar = np.atleast_2d(np.asarray(samples, dtype=np.float32))
    scaled = np.clip(planar * np.float32(gain), -1.0, 1.0)
    return np.round(scaled.T * 32767.0).astype("<i2").tobytes()
