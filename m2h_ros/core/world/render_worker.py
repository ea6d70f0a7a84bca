"""Render processes for BatchEnv (``BatchEnv(render_processes=N)``): fresh poses rendered beside the
stepping process, with a GIL of their own.

Threads share one interpreter lock, and a BatchEnv step holds it for its Python glue, so on two cores
two render threads reach ~1.2x one. A render process takes fresh poses of a step from the same job
list as the stepping process: each claims the next unclaimed job under a shared lock (a fresh render
costs ~15x a pose-cache hit, so claiming one at a time keeps both busy to the end). A process renders
a job into a shared memory map (the pose's render and, without microphone noise, its log-magnitude
spectrogram) with the same functions the env uses (``world.render``), so the numbers do not depend
on who rendered a pose; the env copies them into its outputs and pose cache as it does its own.

Each process keeps its own RIR banks and stored spectra maps (the page cache holds the files once).
The map lives in a file that is unlinked as soon as every process has mapped it, so nothing is left
behind however a process ends.
"""

from __future__ import annotations

import multiprocessing
import os
import sys
import tempfile
import traceback
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Any, NamedTuple

import numpy as np

from m2h_ros.core.audio.stft import StftConfig
from m2h_ros.core.world.acoustics import AcousticsConfig
from m2h_ros.errors import M2HError

SceneKey = tuple[str, str, int]


class RenderJob(NamedTuple):   # a tuple: jobs are pickled to the render processes every step
    """A fresh pose to render: the slot (its clips' spectra in the shared map), the scene, the
    sources (target first), the receiving pose, and whether to add the spectrogram (no noise)."""

    slot: int
    scene: SceneKey
    sources: tuple[int, ...]
    node: int
    heading: int
    spectrogram: bool
    entry: int   # the slot's pose-cache entry to render into; -1: the job's own buffer (no pose cache)


@dataclass(frozen=True)
class RenderSetup:
    """What a render process needs to render like the env (picklable)."""

    n_envs: int
    max_sources: int
    n_fft: int
    n_samples: int
    stft: StftConfig
    acoustics: AcousticsConfig
    rir_cache_dir: Path | None
    stored_rir_spectra: bool
    rir_spectra_mib: float
    pose_cache: int   # entries per slot (BatchEnv's pose caches live in the shared map)


class _SharedArrays:
    """The arrays of the shared map: the claim counter, every slot's clip spectra, every slot's
    pose cache (renders and log-magnitude spectrograms), and, without a pose cache, one render and
    spectrogram per job (at most one job per slot and step)."""

    def __init__(self, setup: RenderSetup, path: str, *, create: bool) -> None:
        b, f, c = setup.n_envs, setup.n_fft // 2 + 1, setup.pose_cache
        spectrogram = (2, setup.stft.n_freq, setup.stft.n_frames)
        jobs = 0 if c else b
        shapes = [("counter", np.int64, (1,)),
                  ("clip_spectra", np.complex64, (b, setup.max_sources, f)),
                  ("cache_renders", np.float32, (b, c, 4, setup.n_samples)),
                  ("cache_spectrograms", np.float32, (b, c, *spectrogram)),
                  ("renders", np.float32, (jobs, 4, setup.n_samples)),
                  ("spectrograms", np.float32, (jobs, *spectrogram))]
        size = sum(int(np.prod(shape)) * np.dtype(dtype).itemsize for _, dtype, shape in shapes)
        self.map = np.memmap(path, np.uint8, "w+" if create else "r+", shape=(size,))
        flat = self.map.view(np.ndarray)   # plain views: indexing an np.memmap pays for its subclass hooks
        offset = 0
        for name, dtype, shape in shapes:
            count = int(np.prod(shape)) * np.dtype(dtype).itemsize
            setattr(self, name, flat[offset:offset + count].view(dtype).reshape(shape))
            offset += count

    def take_job(self) -> int:
        """The next job's index, counted up for the next taker (call it holding the lock)."""
        index = int(self.counter[0])
        self.counter[0] = index + 1
        return index

    def pose_cache(self, slot: int) -> tuple[np.ndarray, np.ndarray]:
        """The arrays of ``slot``'s pose cache (renders, spectrograms)."""
        return self.cache_renders[slot], self.cache_spectrograms[slot]

    def destination(self, job: RenderJob, index: int) -> tuple[np.ndarray, np.ndarray | None]:
        """Where job ``index`` is rendered: (4, S) render and (2, F, T) spectrogram (None: not wanted)."""
        if job.entry >= 0:
            render, spectrogram = self.cache_renders[job.slot, job.entry], self.cache_spectrograms[job.slot, job.entry]
        else:
            render, spectrogram = self.renders[index], self.spectrograms[index]
        return render, spectrogram if job.spectrogram else None


class RenderWorkers:
    """``count`` render processes and the shared map; the env's side of the protocol."""

    def __init__(self, setup: RenderSetup, count: int) -> None:
        context = multiprocessing.get_context("spawn")   # no fork: the parent may hold threads and locks
        directory = "/dev/shm" if os.path.isdir("/dev/shm") else None
        handle, path = tempfile.mkstemp(prefix="m2h_render_", dir=directory)
        os.close(handle)
        self._processes: list[Any] = []
        self._connections: list[Any] = []
        try:
            self.shared = _SharedArrays(setup, path, create=True)
            self._lock = context.Lock()
            for index in range(count):
                parent, child = context.Pipe()
                process = context.Process(target=_serve, args=(child, self._lock, setup, path),
                                          name=f"m2h-render-{index}", daemon=True)
                with _main_module_hidden():
                    process.start()
                child.close()
                self._processes.append(process)
                self._connections.append(parent)
            for connection in self._connections:
                self._receive(connection)   # "ready": the map is open there
        except BaseException:
            self.close()
            raise
        finally:
            os.unlink(path)
        self._jobs = 0

    @property
    def process_ids(self) -> list[int]:
        return [process.pid for process in self._processes]

    def prepare(self, scenes: list[SceneKey]) -> None:
        """Open the RIR banks (or stored spectra) of ``scenes`` in every process and map their pages."""
        for connection in self._connections:
            connection.send(("prepare", scenes))
        for connection in self._connections:
            self._receive(connection)

    def start(self, jobs: list[RenderJob]) -> None:
        """Hand ``jobs`` to every process; they start claiming at once."""
        self.shared.counter[0], self._jobs = 0, len(jobs)
        for connection in self._connections:
            connection.send(("render", jobs))

    def claim(self) -> int | None:
        """The next unclaimed job for the calling process to render itself, or None."""
        while not self._lock.acquire(timeout=1.0):   # a process killed while holding it never gives it back
            if not all(process.is_alive() for process in self._processes):
                raise M2HError(f"a BatchEnv render process ended (exit codes "
                               f"{[p.exitcode for p in self._processes]})")
        try:
            index = self.shared.take_job()
        finally:
            self._lock.release()
        return index if index < self._jobs else None

    def finish(self) -> None:
        """Wait until every process has rendered what it claimed (into the shared map)."""
        for connection in self._connections:
            self._receive(connection)

    def _receive(self, connection: Any) -> Any:
        try:
            kind, value = connection.recv()
        except (EOFError, OSError) as exc:
            codes = [p.exitcode for p in self._processes]
            raise M2HError(f"a BatchEnv render process ended (exit codes {codes})") from exc
        if kind == "error":
            raise M2HError(f"a BatchEnv render process failed:\n{value}")
        return value

    def close(self) -> None:
        for connection in self._connections:
            try:
                connection.send(None)
                connection.close()
            except OSError:
                pass
        for process in self._processes:
            process.join(timeout=5)
            if process.is_alive():
                process.kill()
                process.join()
        self._processes, self._connections = [], []


@contextmanager
def _main_module_hidden() -> Iterator[None]:
    """A spawned child imports the parent's ``__main__`` again (running an unguarded script's top level
    a second time, failing for ``python -``); a render process needs nothing from it, so the child is
    started while ``__main__`` names no file or module."""
    main = sys.modules.get("__main__")
    saved = {name: getattr(main, name) for name in ("__file__", "__spec__") if hasattr(main, name)}
    try:
        if "__file__" in saved:
            del main.__file__
        if "__spec__" in saved:
            main.__spec__ = None
        yield
    finally:
        for name, value in saved.items():
            setattr(main, name, value)


def _serve(connection: Any, lock: Any, setup: RenderSetup, path: str) -> None:
    """A render process: map the shared arrays, then render claimed jobs until told to stop."""
    from m2h_ros.allocator import keep_freed_blocks
    from m2h_ros.core.world.episodes import scene_at
    from m2h_ros.core.world.render import log_magnitude_into, render_pose, source_spectra
    from m2h_ros.core.world.rir_bank import RirBank
    from m2h_ros.core.world.rir_spectra import RirSpectra, StoredRirSpectra

    keep_freed_blocks()
    try:
        shared = _SharedArrays(setup, path, create=False)
        cache = RirSpectra(setup.n_fft, setup.acoustics.n_taps, max_bytes=int(setup.rir_spectra_mib * 2**20))
        scenes: dict[SceneKey, tuple[RirBank, StoredRirSpectra | None]] = {}

        def scene(key: SceneKey) -> tuple[RirBank, StoredRirSpectra | None]:
            if key not in scenes:
                bank = RirBank(scene_at(*key), setup.acoustics, cache_dir=setup.rir_cache_dir, progress=False)
                scenes[key] = bank, StoredRirSpectra(bank, setup.n_fft) if setup.stored_rir_spectra else None
            return scenes[key]

        connection.send(("ready", None))
        while (message := connection.recv()) is not None:
            kind, value = message
            if kind == "prepare":
                for key in value:
                    bank, stored = scene(key)
                    bank.build(progress=False, populate_pages=stored is None)
                    if stored is not None:
                        stored.build(populate_pages=True)
                connection.send(("prepared", None))
                continue
            jobs = value
            while True:
                with lock:
                    index = shared.take_job()
                if index >= len(jobs):
                    break
                job = jobs[index]
                render, spectrogram = shared.destination(job, index)
                found = source_spectra(*scene(job.scene), cache, job.sources, job.node, job.heading)
                render[...] = render_pose(found, shared.clip_spectra[job.slot], np.float32(1.0 / len(job.sources)),
                                          n_fft=setup.n_fft, n_samples=setup.n_samples)
                if spectrogram is not None:
                    log_magnitude_into(render[2:], spectrogram, config=setup.stft)
            connection.send(("done", None))
    except (EOFError, KeyboardInterrupt):
        pass
    except BaseException:
        try:
            connection.send(("error", traceback.format_exc()))
        except OSError:
            pass
