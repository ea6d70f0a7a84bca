"""Cut a live multichannel stream into the separator's overlapping frames, resampled and stamped.

A microphone delivers blocks of samples at its own rate; the separator wants frames of ``frame``
samples at 16 kHz, one every ``hop`` samples. ``Framer`` keeps the stream's recent samples and emits
each frame once its last sample (plus a few samples of filter context) has arrived. Resampling uses
the same polyphase filter as ``scipy.signal.resample_poly`` on the whole stream, applied to each frame
with enough context on both sides that the result equals the whole-stream resampling: frames cut live
hold exactly what an offline resampling of the recording would (a test checks it). Each frame is
stamped with the capture time of its first sample, from the stamp of the block that held it.
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass

import numpy as np
import scipy.signal

from m2h_ros.errors import AudioError, ConfigError

# scipy.signal.resample_poly's default filter: a Kaiser window of 10 * max(up, down) taps on each side
# of its centre, at the upsampled rate.
_HALF_TAPS_PER_RATIO = 10


@dataclass(frozen=True)
class FrameLayout:
    """Frame geometry in both rates: ``frame`` / ``hop`` output samples, ``up`` / ``down`` the reduced
    resampling ratio, ``pad`` input samples of filter context kept on each side of a frame."""

    input_rate: int
    output_rate: int
    frame: int
    hop: int

    @classmethod
    def of(cls, *, input_rate: int, output_rate: int, frame_s: float, hop_s: float) -> FrameLayout:
        frame, hop = round(frame_s * output_rate), round(hop_s * output_rate)
        for name, seconds, samples in (("frame", frame_s, frame), ("hop", hop_s, hop)):
            if samples <= 0 or not math.isclose(samples, seconds * output_rate, abs_tol=1e-6):
                raise ConfigError(f"{name} of {seconds} s is not a whole number of samples at {output_rate} Hz")
        layout = cls(input_rate, output_rate, frame, hop)
        # A hop must start each frame on the same output sample grid as the whole stream's resampling.
        if hop % layout.up or (frame * layout.down) % layout.up:
            raise ConfigError(f"frame {frame_s} s / hop {hop_s} s do not fall on whole samples at both "
                              f"{input_rate} Hz and {output_rate} Hz; choose multiples of "
                              f"{layout.up / output_rate:g} s")
        return layout

    @property
    def up(self) -> int:
        return self.output_rate // math.gcd(self.input_rate, self.output_rate)

    @property
    def down(self) -> int:
        return self.input_rate // math.gcd(self.input_rate, self.output_rate)

    @property
    def raw_frame(self) -> int:
        return self.frame * self.down // self.up

    @property
    def raw_hop(self) -> int:
        return self.hop * self.down // self.up

    @property
    def pad(self) -> int:
        if self.up == self.down:
            return 0
        half = math.ceil(_HALF_TAPS_PER_RATIO * max(self.up, self.down) / self.up) + 1
        return self.down * math.ceil(half / self.down)  # a multiple of down: whole output samples

    @property
    def latency_samples(self) -> int:
        """Input samples a frame waits for after its last one (the filter's right-hand context)."""
        return self.pad


@dataclass(frozen=True)
class Frame:
    samples: np.ndarray  # (channels, frame) float32 at the output rate
    stamp_ns: int        # capture time of the frame's first sample
    index: int           # frame number since the stream (re)started


class Framer:
    """Blocks in, frames out. ``restart()`` after lost samples: frames never span a gap."""

    def __init__(self, layout: FrameLayout, channels: int):
        self.layout, self.channels = layout, channels
        self._end = self._next = 0
        self.restart()

    def restart(self) -> int:
        """Forget the stream so far (samples were lost); returns the frames begun and now abandoned."""
        begun = max(-(-self._end // self.layout.raw_hop) - self._next, 0)  # their first sample had arrived
        # The stream starts after `pad` zeros, as resample_poly pads a whole recording.
        self._buffer = np.zeros((self.channels, self.layout.pad), np.float32)
        self._start = -self.layout.pad  # stream index of the buffer's first sample
        self._end = 0                   # stream index after the last sample received
        self._next = 0                  # index of the next frame to emit
        self._stamps: deque[tuple[int, int]] = deque()  # (stream index of a block's first sample, its stamp)
        return begun

    def push(self, block: np.ndarray, stamp_ns: int) -> list[Frame]:
        """Add a (channels, n) block whose first sample was captured at ``stamp_ns``; return the frames
        it completes."""
        block = np.asarray(block, np.float32)
        if block.ndim != 2 or block.shape[0] != self.channels:
            raise AudioError(f"a block of shape {block.shape}; expected ({self.channels}, n)")
        self._stamps.append((self._end, int(stamp_ns)))
        self._buffer = np.concatenate([self._buffer, block], axis=1)
        self._end += block.shape[1]
        lay = self.layout
        frames = []
        while (first := self._next * lay.raw_hop) + lay.raw_frame + lay.pad <= self._end:
            lo = first - lay.pad - self._start
            window = self._buffer[:, lo: lo + lay.raw_frame + 2 * lay.pad]
            if lay.up != lay.down:
                skip = lay.pad * lay.up // lay.down
                window = scipy.signal.resample_poly(window, lay.up, lay.down, axis=1)[:, skip: skip + lay.frame]
            frames.append(Frame(np.ascontiguousarray(window, np.float32), self._stamp_of(first), self._next))
            self._next += 1
        self._trim()
        return frames

    def _stamp_of(self, index: int) -> int:
        start, stamp = next((s, t) for s, t in reversed(self._stamps) if s <= index)
        return stamp + round((index - start) * 1e9 / self.layout.input_rate)

    def _trim(self) -> None:
        keep_from = self._next * self.layout.raw_hop - self.layout.pad
        if keep_from > self._start:
            self._buffer = self._buffer[:, keep_from - self._start:]
            self._start = keep_from
        while len(self._stamps) > 1 and self._stamps[1][0] <= self._next * self.layout.raw_hop:
            self._stamps.popleft()
