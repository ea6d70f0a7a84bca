"""Per-scene bank of binaural RIRs for every (source node, receiver node, heading), cached on disk.

Layout: ``data_dir()/rir_banks/v<VERSION>/<scene fingerprint>-<config digest>/src_<node>.npy``,
one (N, row_length) array per source node (see ``acoustics.AcousticsConfig.row_length``), computed
lazily on first use or all at once with ``build()`` (local processes or Ray tasks: ``bank_build``),
written atomically (temporary file + rename) and memory-mapped on read. The bank's folder may also
hold ``spectra_<n_fft>/``, the RIRs' spectra (``rir_spectra.StoredRirSpectra``).
"""

from __future__ import annotations

import json
import mmap
import os
import threading
from pathlib import Path
from typing import Any

import numpy as np

from m2h_ros.core.world.acoustics import N_HEADINGS, VERSION, AcousticsConfig, simulate_source
from m2h_ros.core.world.bank_build import compute_sources
from m2h_ros.errors import CacheError, ConfigError
from m2h_ros.paths import data_dir


def bank_dir(scene: Any, config: AcousticsConfig, cache_dir: Path | None = None) -> Path:
    """Folder of one scene's bank under ``cache_dir`` (default ``data_dir()/rir_banks``)."""
    root = Path(cache_dir) if cache_dir is not None else data_dir() / "rir_banks"
    return root / f"v{VERSION}" / f"{scene.fingerprint()}-{config.digest()}"


def save_atomic(path: Path, array: np.ndarray) -> Path:
    """``np.save`` through a temporary file and a rename: readers see the old state or the whole file."""
    tmp = path.with_name(f".{path.name}.{os.getpid()}.{threading.get_ident()}.tmp")
    with open(tmp, "wb") as handle:
        np.save(handle, array)
        handle.flush()
        os.fsync(handle.fileno())
    os.replace(tmp, path)
    return path


def load_mapped(path: Path, shape: tuple[int, ...], dtype: np.dtype | str, *, what: str) -> np.ndarray:
    """The memory-mapped array of ``path`` as a plain ndarray view (indexing an np.memmap pays for
    its subclass hooks), checked against the expected shape and dtype."""
    try:
        array = np.load(path, mmap_mode="r")
    except (ValueError, OSError, EOFError) as err:
        raise CacheError(f"{what} file {path} is corrupt ({err}); delete it to rebuild") from err
    if array.shape != tuple(shape) or array.dtype != np.dtype(dtype):
        raise CacheError(f"{what} file {path} holds {array.dtype}{array.shape}, expected "
                         f"{np.dtype(dtype)}{tuple(shape)}; delete it to rebuild")
    return array.view(np.ndarray)


_MADV_POPULATE_READ = 22   # Linux >= 5.14; Python's mmap module names it from 3.13 on


def populate(array: np.ndarray) -> None:
    """Map every page of a :func:`load_mapped` array into this process now (``MADV_POPULATE_READ``,
    reading from disk what the page cache lacks), so that later work takes no page fault for them;
    where the kernel lacks it, pages map on first touch."""
    base = array.base
    while base is not None and not isinstance(base, mmap.mmap):
        base = getattr(base, "base", None)
    if base is not None:
        try:
            base.madvise(_MADV_POPULATE_READ)
        except OSError:
            pass


class RirBank:
    """Binaural RIRs of one scene; ``rirs()`` gathers a batch, computing missing source nodes."""

    def __init__(self, scene: Any, config: AcousticsConfig = AcousticsConfig(), *,
                 cache_dir: Path | None = None, progress: bool = True) -> None:
        self.scene = scene
        self.config = config
        self.progress = progress
        self.n_nodes = len(scene.grid.positions)
        self.directory = bank_dir(scene, config, cache_dir)
        self.directory.mkdir(parents=True, exist_ok=True)
        self._write_meta()
        self._maps: list[np.ndarray | None] = [None] * self.n_nodes

    def _write_meta(self) -> None:
        meta = self.directory / "meta.json"
        if not meta.exists():
            text = json.dumps({"scene_id": self.scene.scene_id, "fingerprint": self.scene.fingerprint(),
                               "version": VERSION, "n_nodes": self.n_nodes,
                               "config": self.config.__dict__}, indent=1)
            tmp = meta.with_name(f".meta.{os.getpid()}.tmp")
            tmp.write_text(text)
            os.replace(tmp, meta)

    def path(self, node: int) -> Path:
        return self.directory / f"src_{node:04d}.npy"

    def missing(self) -> list[int]:
        """Source nodes with no file on disk yet."""
        return [n for n in range(self.n_nodes) if not self.path(n).exists()]

    def store(self, node: int, rows: np.ndarray) -> Path:
        """Write one source node's rows (``simulate_source``'s) to its file, atomically."""
        expected = (self.n_nodes, self.config.row_length)
        if rows.shape != expected or rows.dtype != np.dtype(self.config.storage_dtype):
            raise CacheError(f"rows of source node {node} are {rows.dtype}{rows.shape}, the bank "
                             f"{self.directory} holds {np.dtype(self.config.storage_dtype)}{expected}")
        return save_atomic(self.path(node), rows)

    def build(self, *, progress: bool = True, workers: int = 1, ray_address: str | None = None,
              populate_pages: bool = False) -> int:
        """Compute every missing source node now, ``workers`` local processes or Ray tasks
        (``ray_address``: ``bank_build.compute_sources``), then open them all (and with
        ``populate_pages`` map their pages into this process: :func:`populate`). Returns how many
        source nodes were computed (files already present are kept)."""
        todo = self.missing()
        compute_sources(self.scene, self.config, todo, self.store, workers=workers, ray_address=ray_address,
                        progress=progress and self.progress, desc=f"RIR bank {self.scene.scene_id}")
        for node in range(self.n_nodes):
            rows = self._source(node)
            if populate_pages:
                populate(rows)
        return len(todo)

    def _source(self, node: int) -> np.ndarray:
        """The memory-mapped rows of one source node, computed first if absent."""
        rows = self._maps[node]
        if rows is not None:
            return rows
        path = self.path(node)
        if not path.exists():
            self.store(node, simulate_source(self.scene, node, self.config))
        rows = self._maps[node] = load_mapped(path, (self.n_nodes, self.config.row_length),
                                              self.config.storage_dtype, what="RIR bank")
        return rows

    def rirs(self, source_nodes, receiver_nodes, headings, *, out: np.ndarray | None = None) -> np.ndarray:
        """(B, 2, T) float32 binaural RIRs for B (source node, receiver node, heading) triples.

        ``out``: a (B, 2, >= T) float32 array to write them into (its first T samples; the rest is
        left as it is, e.g. the zero padding of a convolution buffer); returned.
        """
        # Python lists: the env asks for one or two RIRs at a time, where numpy's checks cost more
        # than the copies.
        sources, receivers, heads = (np.asarray(values, dtype=np.int64).ravel().tolist()
                                     for values in (source_nodes, receiver_nodes, headings))
        if not len(sources) == len(receivers) == len(heads):
            raise ConfigError(f"rirs() needs equally long index arrays, got {len(sources)}, "
                              f"{len(receivers)}, {len(heads)}")
        for name, values, limit in (("source", sources, self.n_nodes), ("receiver", receivers, self.n_nodes),
                                    ("heading", heads, 4)):
            if values and (min(values) < 0 or max(values) >= limit):
                raise ConfigError(f"{name} index out of range 0..{limit - 1}: {values}")
        n_early, n_taps = self.config.n_early, self.config.n_taps
        if out is None:
            out = np.empty((len(sources), 2, n_taps), dtype=np.float32)
        elif out.dtype != np.float32 or out.ndim != 3 or out.shape[:2] != (len(sources), 2) \
                or out.shape[2] < n_taps:
            raise ConfigError(f"rirs(out=...) needs a float32 ({len(sources)}, 2, >= {n_taps}) array, "
                              f"got {out.dtype} {out.shape}")
        # Only the late part and the asked heading's early part are read, as contiguous slices
        # straight into the output (a fancy index would copy them once more).
        late_start = N_HEADINGS * 2 * n_early
        for item, (source, receiver, heading) in enumerate(zip(sources, receivers, heads)):
            row = self._source(source)[receiver]
            out[item, :, :n_taps] = row[late_start:].reshape(2, n_taps)
            start = heading * 2 * n_early
            out[item, :, :n_early] += row[start: start + 2 * n_early].reshape(2, n_early)
        return out

    def size_on_disk(self) -> int:
        """Bytes of the source files present."""
        return sum(p.stat().st_size for p in self.directory.glob("src_*.npy"))

