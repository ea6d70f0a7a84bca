"""Spectra of binaural RIRs: LRU-cached in memory and bounded in bytes, or all of a scene's stored on disk.

The environment convolves every source's clip with the RIR of (source node, receiver node,
heading) in the frequency domain. That RIR's spectrum does not depend on the episode, so all slots of
a scene (and later episodes there) can reuse it instead of transforming the RIR again at every
fresh pose. One entry is the rfft of the (2, T) RIR zero-padded to ``n_fft``: (2, n_fft // 2 + 1)
complex64, 192 KiB for 0.5 s RIRs at n_fft 24000, 256 KiB for 1 s RIRs at 32000. The values are
those of an rfft of the padded RIR batch itself (pocketfft transforms each row on its own), so the
cache changes no number.
"""

from __future__ import annotations

import threading
from collections import OrderedDict
from collections.abc import Sequence
from pathlib import Path

import numpy as np
from scipy import fft as sfft

from m2h_ros.core.world.acoustics import N_HEADINGS
from m2h_ros.core.world.rir_bank import RirBank, load_mapped, populate, save_atomic
from m2h_ros.errors import ConfigError


def convolution_length(*, clip_samples: int, n_taps: int) -> int:
    """FFT length of one linear convolution of a clip with a full RIR, without wrap-around into
    the clip's samples: the length of every RIR spectrum the environment uses."""
    return sfft.next_fast_len(clip_samples + n_taps - 1, real=True)


class RirSpectra:
    """(2, F) complex64 RIR spectra per (RIR bank, source, receiver, heading); thread-safe LRU.

    ``max_bytes`` bounds the entries held (0 keeps none: every call transforms afresh). Cached
    arrays are read-only and stay valid after eviction (eviction only drops the cache's reference);
    callers must not write to any returned array.
    """

    def __init__(self, n_fft: int, n_taps: int, *, max_bytes: int) -> None:
        if isinstance(max_bytes, bool) or not isinstance(max_bytes, (int, np.integer)) or max_bytes < 0:
            raise ConfigError(f"max_bytes={max_bytes!r} must be a non-negative int")
        if n_taps > n_fft:
            raise ConfigError(f"n_fft={n_fft} is shorter than the RIRs ({n_taps} taps)")
        self.n_fft, self.n_taps = int(n_fft), int(n_taps)
        self.entry_bytes = 2 * (self.n_fft // 2 + 1) * np.dtype(np.complex64).itemsize
        self.capacity = int(max_bytes) // self.entry_bytes
        self.hits = self.misses = 0
        self._entries: OrderedDict[tuple[RirBank, int, int, int], np.ndarray] = OrderedDict()
        self._lock = threading.Lock()
        self._local = threading.local()

    def __len__(self) -> int:
        return len(self._entries)

    @property
    def nbytes(self) -> int:
        return len(self._entries) * self.entry_bytes

    def spectra(self, requests: Sequence[tuple[RirBank, int, int, int]]) -> list[np.ndarray]:
        """The spectrum of each (bank, source node, receiver node, heading) RIR, in order."""
        with self._lock:
            found = [self._entries.get(key) for key in requests]
            for key, entry in zip(requests, found):
                if entry is not None:
                    self._entries.move_to_end(key)
            missing = [i for i, entry in enumerate(found) if entry is None]
            self.hits += len(requests) - len(missing)
            self.misses += len(missing)
        if not missing:
            return found
        # The missing RIRs in one FFT (pocketfft vectorises over >= 4 rows: 2-3x faster than 1-2),
        # gathered into this thread's zero-padded buffer: only the first n_taps samples are ever
        # written, so its padding stays zero and needs no clearing (rfft leaves its input as is).
        rirs = self._buffer(len(missing))
        by_bank: dict[RirBank, list[int]] = {}
        for i in missing:
            by_bank.setdefault(requests[i][0], []).append(i)
        missing, row = [i for group in by_bank.values() for i in group], 0   # by bank: one gather each
        for bank, group in by_bank.items():
            sources, receivers, headings = zip(*(requests[i][1:] for i in group))
            bank.rirs(sources, receivers, headings, out=rirs[row:row + len(group)])
            row += len(group)
        new = sfft.rfft(rirs, axis=-1)
        if not self.capacity:
            for i, spectrum in zip(missing, new):
                found[i] = spectrum
            return found
        # One array per entry (a copy), so that an evicted entry frees its own memory.
        with self._lock:
            for i, spectrum in zip(missing, new):
                found[i] = spectrum.copy()
                found[i].flags.writeable = False
                self._entries[requests[i]] = found[i]
            while len(self._entries) > self.capacity:
                self._entries.popitem(last=False)
        return found

    def _buffer(self, rows: int) -> np.ndarray:
        """(rows, 2, n_fft) float32 of the calling thread, zero beyond n_taps."""
        buffer = getattr(self._local, "buffer", None)
        if buffer is None or len(buffer) < rows:
            buffer = self._local.buffer = np.zeros((rows, 2, self.n_fft), np.float32)
        return buffer[:rows]

    def clear(self) -> None:
        with self._lock:
            self._entries.clear()


class StoredRirSpectra:
    """Every RIR spectrum of one RIR bank, stored on disk next to it and memory-mapped.

    ``spectra_<n_fft>/src_<node>.npy`` holds (receivers, headings, 2, n_fft // 2 + 1) complex64 for
    one source node: 250 KiB per (receiver, heading) at n_fft 32000, about 1 GiB for a 32-node scene
    (the RIR bank itself is 175 MiB). Each file is computed from the bank on first use (or all at
    once with ``build()``), written atomically. The values are those ``RirSpectra`` computes (each
    row's rfft does not depend on the batch it is in), so using them changes no number; a fresh
    render then skips the RIR gather and its FFT (docs/design/simulator.md). The page cache holds the
    files once for every process reading them.
    """

    def __init__(self, bank: RirBank, n_fft: int) -> None:
        if bank.config.n_taps > n_fft:
            raise ConfigError(f"n_fft={n_fft} is shorter than the RIRs ({bank.config.n_taps} taps)")
        self.bank, self.n_fft = bank, int(n_fft)
        self.directory = bank.directory / f"spectra_{self.n_fft}"
        self.directory.mkdir(parents=True, exist_ok=True)
        self._shape = (bank.n_nodes, N_HEADINGS, 2, self.n_fft // 2 + 1)
        self._maps: list[np.ndarray | None] = [None] * bank.n_nodes

    def path(self, source: int) -> Path:
        return self.directory / f"src_{source:04d}.npy"

    def spectrum(self, source: int, receiver: int, heading: int) -> np.ndarray:
        """(2, F) read-only spectrum of the RIR from ``source`` to (``receiver``, ``heading``)."""
        n = self.bank.n_nodes
        if not (0 <= source < n and 0 <= receiver < n and 0 <= heading < N_HEADINGS):
            raise ConfigError(f"source/receiver node must be in [0, {n}) and heading in [0, {N_HEADINGS}), "
                              f"got {source}, {receiver}, {heading}")
        rows = self._maps[source]
        if rows is None:
            rows = self._source(source)
        return rows[receiver, heading]

    def build(self, *, populate_pages: bool = False) -> None:
        """Compute every missing source file now and map them all (and with ``populate_pages`` map
        their pages into this process: ``rir_bank.populate``)."""
        for source in range(self.bank.n_nodes):
            rows = self._source(source)
            if populate_pages:
                populate(rows)

    def size_on_disk(self) -> int:
        return sum(p.stat().st_size for p in self.directory.glob("src_*.npy"))

    def _source(self, source: int) -> np.ndarray:
        path = self.path(source)
        if not path.exists():
            save_atomic(path, self._compute(source))
        rows = self._maps[source] = load_mapped(path, self._shape, np.complex64, what="RIR spectra")
        return rows

    def _compute(self, source: int) -> np.ndarray:
        """(receivers, headings, 2, F): the rfft of every zero-padded RIR of ``source``."""
        n_nodes = self.bank.n_nodes
        receivers, headings = np.divmod(np.arange(n_nodes * N_HEADINGS), N_HEADINGS)
        rirs = np.zeros((len(receivers), 2, self.n_fft), np.float32)
        self.bank.rirs(np.full(len(receivers), source), receivers, headings, out=rirs)
        return sfft.rfft(rirs, axis=-1).reshape(self._shape)
