"""PCM: float audio as signed 16-bit PCM, the format players take (Foxglove's RawAudio ``pcm-s16``), and
interleaved PCM bytes as audio drivers send them back to planar float32.

Decoded format names are GStreamer's, which ros-drivers' audio_capture puts in ``AudioInfo.sample_format``."""

from __future__ import annotations

import numpy as np

from m2h_ros.errors import AudioError

# format -> (numpy dtype of one sample, scale to [-1, 1], offset); S24LE (3 bytes) is unpacked apart.
_FORMATS = {"S16LE": ("<i2", 1 / 2**15, 0.0), "S32LE": ("<i4", 1 / 2**31, 0.0), "F32LE": ("<f4", 1.0, 0.0),
            "F64LE": ("<f8", 1.0, 0.0), "U8": ("u1", 1 / 2**7, -1.0), "S8": ("i1", 1 / 2**7, 0.0)}
SAMPLE_FORMATS = (*_FORMATS, "S24LE")


def decode_pcm(data: bytes, *, sample_format: str, channels: int) -> np.ndarray:
    """(channels, n) float32 from interleaved little-endian PCM ``data``."""
    fmt = sample_format.upper()
    if fmt == "S24LE":
        raw = np.frombuffer(data, np.uint8)
        width = 3
    elif fmt in _FORMATS:
        raw = np.frombuffer(data, _FORMATS[fmt][0])
        width = raw.itemsize
    else:
        raise AudioError(f"sample format {sample_format!r}: decodable are {', '.join(SAMPLE_FORMATS)}")
    if channels < 1 or len(data) % (width * channels):
        raise AudioError(f"{len(data)} bytes are not whole {fmt} frames of {channels} channel(s)")
    if fmt == "S24LE":
        triples = raw.reshape(-1, 3).astype(np.int32)
        values = (triples[:, 0] | (triples[:, 1] << 8) | (triples[:, 2] << 16)) << 8 >> 8  # sign-extend
        samples = values.astype(np.float32) / 2**23
    else:
        _, scale, offset = _FORMATS[fmt]
        samples = raw.astype(np.float32) * np.float32(scale) + np.float32(offset)
    return np.ascontiguousarray(samples.reshape(-1, channels).T)


def pcm_int16(samples: np.ndarray, *, gain: float) -> bytes:
    """``(channels, n)`` (or ``(n,)``) float samples times ``gain``, clipped to [-1, 1], as interleaved
    little-endian int16 frames.

    The simulator's audio is not in [-1, 1] (clips are normalised to an average power of 1.2, mixtures
    peak near 20): one fixed gain, not a per-frame one, keeps loudness comparable from step to step."""
    planar = np.atleast_2d(np.asarray(samples, dtype=np.float32))
    scaled = np.clip(planar * np.float32(gain), -1.0, 1.0)
    return np.round(scaled.T * 32767.0).astype("<i2").tobytes()
