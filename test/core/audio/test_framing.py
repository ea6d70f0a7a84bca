"""Framer: live frames equal an offline resampling of the whole recording, stamps follow the blocks,
and a restart never lets a frame span lost samples."""

import numpy as np
import pytest
import scipy.signal

from m2h_ros.core.audio.framing import FrameLayout, Framer
from m2h_ros.errors import ConfigError


def cut(framer: Framer, stream: np.ndarray, rate: int, seed: int = 0) -> list:
    rng, frames, pos = np.random.default_rng(seed), [], 0
    while pos < stream.shape[1]:
        n = int(rng.integers(50, 4000))
        frames += framer.push(stream[:, pos: pos + n], 10**9 + pos * 10**9 // rate)
        pos += n
    return frames


@pytest.mark.parametrize("rate", [16000, 22050, 44100, 48000])
def test_frames_equal_the_whole_recording_resampled(rate):
    layout = FrameLayout.of(input_rate=rate, output_rate=16000, frame_s=1.0, hop_s=0.5)
    stream = np.random.default_rng(1).standard_normal((2, rate * 41 // 10)).astype(np.float32)  # 4 s + filter context
    whole = scipy.signal.resample_poly(stream, layout.up, layout.down, axis=1)
    frames = cut(Framer(layout, 2), stream, rate)
    assert [f.index for f in frames] == list(range(7))
    for f in frames:
        np.testing.assert_allclose(f.samples, whole[:, f.index * 8000: f.index * 8000 + 16000], atol=1e-5)
        assert abs(f.stamp_ns - (10**9 + f.index * 5 * 10**8)) <= 1


def test_a_restart_abandons_the_frames_begun_and_starts_afresh():
    layout = FrameLayout.of(input_rate=16000, output_rate=16000, frame_s=1.0, hop_s=0.5)
    framer = Framer(layout, 1)
    assert len(framer.push(np.ones((1, 20000)), 0)) == 1  # frame 0 done, frame 1 (from 8000) begun
    assert framer.restart() == 2   # frames 1 and 2 had their first samples
    frames = framer.push(np.full((1, 16000), 2.0), 5 * 10**9)
    assert len(frames) == 1 and np.all(frames[0].samples == 2.0) and frames[0].stamp_ns == 5 * 10**9


def test_hops_off_the_sample_grid_are_refused():
    with pytest.raises(ConfigError, match="hop"):
        FrameLayout.of(input_rate=44100, output_rate=16000, frame_s=1.0, hop_s=0.0001)
    with pytest.raises(ConfigError, match="whole samples at both"):
        FrameLayout.of(input_rate=44100, output_rate=16000, frame_s=1.0, hop_s=0.5003125)
