"""Simulator throughput: environment steps/s for 1 and 16 batched envs, with and without camera.

    python scripts/bench/sim.py [--steps 200] [--threads 2] [--episodes 1000] [--build-workers 2]
                                [--repeats 3] [--rir-length 0.5] [--rir-spectra-mib 0] [--fresh-build]
                                [--stored-rir-spectra] [--render-processes 1] [--spectrogram]

Uses the test split's default scenes and the default acoustics; builds (or reuses) their RIR banks
under data_dir() first and reports their size per scene (and the build time of what was missing);
--fresh-build also times a full build of every scene into a temporary cache with
scripts/bench/acoustics.py; --stored-rir-spectra runs every case with ``BatchEnv(stored_rir_spectra=True)``
(building the spectrum files first and reporting their size); --render-processes N gives the
throughput cases' BatchEnv N render processes (their CPU is added to the CPU figures; the page
faults are this process's). Sound library: the full default
one if it is built, else the --small one (built if missing); the output says which. Each throughput
case runs --repeats times, each in a fresh process with warm caches, and reports its peak RSS, its
minor page faults per env step, the MiB it read from disk (files the page cache had dropped) and the
load average before it (other jobs on the cores slow every
figure); first, how many cores two processes get at once (``m2h_ros.machine.cores_available``). Then the cost of a fresh render:
CPU per env step of 16 envs that render every step (no pose cache, camera on, 1 thread) beside the
bare FFT work such a step needs (RIR rffts, inverse FFTs; the STFT only with --spectrogram), timed in the same process, best of 5
blocks each. Last, the sanity figure:
over the near-target, unheard test episodes, the raw mixture's SI-SDR as an estimate of the target,
at the start pose and at the target's node (heading 0); the second must be higher.
"""

from __future__ import annotations

import argparse
import dataclasses
import importlib.util
import multiprocessing
import os
import resource
import time
from pathlib import Path
from queue import Empty

import numpy as np
from scipy import fft as sfft

from m2h_ros.core.audio.metrics import si_sdr
from m2h_ros.core.audio.stft import DEFAULT_STFT, rebuild_ground_truth_phase, stft
from m2h_ros.core.sounds.library import SoundLibrary, SoundLibraryConfig
from m2h_ros.core.world.acoustics import AcousticsConfig
from m2h_ros.core.world.env import BatchEnv, EnvConfig
from m2h_ros.core.world.episodes import EpisodeConfig, episodes_for
from m2h_ros.core.world.rir_bank import RirBank
from m2h_ros.core.world.rir_spectra import StoredRirSpectra, convolution_length
from m2h_ros.core.world.scene import load_split
from m2h_ros.errors import CacheError
from m2h_ros.machine import availability_line, peak_rss_mib, process_cpu_seconds

SPLIT = "test"


def open_library() -> tuple[SoundLibrary, str]:
    try:
        return SoundLibrary.load(), "full default library"
    except CacheError:
        pass
    try:
        return SoundLibrary.load(SoundLibraryConfig.small()), "--small library (the full one is not built)"
    except CacheError:
        return (SoundLibrary.build(SoundLibraryConfig.small()),
                "--small library, built now (the full one is not built)")


def build_banks(acoustics: AcousticsConfig, workers: int, *, stored_spectra_fft: int | None) -> None:
    """Build (or reuse) the split's RIR banks, and with ``stored_spectra_fft`` their stored spectra."""
    print(f"RIR banks, {SPLIT} split, default scenes, {acoustics.rir_length} s RIRs, "
          f"{acoustics.storage_dtype}:")
    for scene in load_split(SPLIT):
        bank = RirBank(scene, acoustics, progress=False)
        todo = len(bank.missing())
        start = time.perf_counter()
        bank.build(workers=workers, progress=True)
        seconds = time.perf_counter() - start
        built = (f"built {todo} sources in {seconds:.1f} s ({seconds / todo:.2f} s/source, "
                 f"{workers} workers)") if todo else "already cached"
        print(f"  {scene.scene_id}: {scene.grid.n_nodes} nodes, {bank.size_on_disk() / 2**20:.1f} MiB "
              f"on disk, {built}")
        if stored_spectra_fft is not None:
            spectra = StoredRirSpectra(bank, stored_spectra_fft)
            todo = sum(not spectra.path(n).exists() for n in range(bank.n_nodes))
            start = time.perf_counter()
            spectra.build()
            built = f"built {todo} sources in {time.perf_counter() - start:.1f} s" if todo else "already stored"
            print(f"    stored RIR spectra: {spectra.size_on_disk() / 2**30:.2f} GiB on disk, {built}")


def fresh_builds(workers: int) -> None:
    """scripts/bench/acoustics.py on every scene of the split: build time from scratch, size, gather."""
    spec = importlib.util.spec_from_file_location("acoustics_bench", Path(__file__).with_name("acoustics.py"))
    acoustics_bench = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(acoustics_bench)
    saved = os.environ.get("M2H_DATA_DIR")
    try:
        for index in range(len(load_split(SPLIT))):
            acoustics_bench.main(["--split", SPLIT, "--index", str(index), "--workers", str(workers)])
    finally:   # that script points M2H_DATA_DIR at its temporary cache
        if saved is None:
            os.environ.pop("M2H_DATA_DIR", None)
        else:
            os.environ["M2H_DATA_DIR"] = saved


def throughput(n_envs: int, camera: bool, steps: int, threads: int, render_processes: int, pose_cache: int,
               spectra_mib: float, stored_spectra: bool, spectrogram: bool, acoustics: AcousticsConfig,
               episode_config: EpisodeConfig, queue) -> None:
    """Runs in a fresh process: steps/s of one BatchEnv with warm caches, and the peak RSS (CPU: this
    process and its render processes)."""
    library, _ = open_library()
    episodes = episodes_for(episode_config, library)
    env = BatchEnv(episodes, library, n_envs=n_envs, threads=threads, pose_cache=pose_cache,
                   rir_spectra_mib=spectra_mib, stored_rir_spectra=stored_spectra, render_processes=render_processes,
                   config=EnvConfig(camera=camera, acoustics=acoustics, spectrogram=spectrogram))
    env.prepare(progress=False)
    env.reset()
    actions = np.random.default_rng(0).integers(4, size=(steps + 20, n_envs))
    for batch in actions[:20]:
        env.step(batch)
    helpers = env.render_process_ids
    wall, cpu = time.perf_counter(), time.process_time() + sum(map(process_cpu_seconds, helpers))
    before = resource.getrusage(resource.RUSAGE_SELF)
    for batch in actions[20:]:
        env.step(batch)
    wall, cpu = time.perf_counter() - wall, time.process_time() + sum(map(process_cpu_seconds, helpers)) - cpu
    usage = resource.getrusage(resource.RUSAGE_SELF)
    env.close()
    queue.put((n_envs * steps / wall, 1e3 * cpu / (n_envs * steps), peak_rss_mib(),
               env.pose_cache_hit_rate, env.rir_spectra_hit_rate, (usage.ru_minflt - before.ru_minflt) / (n_envs * steps),
               (usage.ru_inblock - before.ru_inblock) * 512 / 2**20))


def _best_cpu_ms(work, repeats: int = 5) -> float:
    """Least CPU ms of ``repeats`` calls of ``work`` (the least disturbed by other jobs)."""
    best = np.inf
    for _ in range(repeats):
        start = time.process_time()
        work()
        best = min(best, time.process_time() - start)
    return 1e3 * best


def fresh_render(stored_spectra: bool, spectrogram: bool, acoustics: AcousticsConfig, episode_config: EpisodeConfig,
                 queue) -> None:
    """Runs in a fresh process: CPU per env step when every step renders afresh, and the bare FFT
    work of one such step, both per env step of 16 envs (camera on, 1 thread; with stored RIR
    spectra, no RIR rfft)."""
    library, _ = open_library()
    env = BatchEnv(episodes_for(episode_config, library), library, n_envs=16, pose_cache=0,
                   stored_rir_spectra=stored_spectra,
                   config=EnvConfig(camera=True, acoustics=acoustics, spectrogram=spectrogram))
    env.prepare(progress=False)
    env.reset()
    actions = iter(np.random.default_rng(0).integers(1, 4, size=(200, env.n_envs)))   # no Stop
    block = 20

    def steps() -> None:
        for _ in range(block):
            env.step(next(actions))
    steps()
    fresh = _best_cpu_ms(steps) / (block * env.n_envs)
    # The same transforms on arrays of the same shapes, batched over the 16 envs: every source's
    # (2, T) RIR forward at the convolution length, target + mixture (4 rows) back, the STFT frames.
    stft_config, rng = env.config.stft, np.random.default_rng(0)
    n_fft = convolution_length(clip_samples=env.n_samples, n_taps=acoustics.n_taps)
    rirs = rng.standard_normal((env.n_envs, env.max_sources * 2, n_fft)).astype(np.float32)
    renders = sfft.rfft(rng.standard_normal((env.n_envs, 4, n_fft)).astype(np.float32), axis=-1)
    frames = rng.standard_normal((env.n_envs, 2 * stft_config.n_frames, stft_config.n_fft)).astype(np.float32)
    parts = {"RIR rfft": lambda: sfft.rfft(rirs, axis=-1),
             "inverse": lambda: sfft.irfft(renders, n_fft, axis=-1),
             "STFT": lambda: sfft.rfft(frames, axis=-1)}
    if stored_spectra:
        del parts["RIR rfft"]
    if not env.config.spectrogram:   # no spectrogram observation, no STFT
        del parts["STFT"]
    fft = {name: _best_cpu_ms(work) / env.n_envs for name, work in parts.items()}
    env.close()
    queue.put((fresh, fft, n_fft))


def sanity(library: SoundLibrary, episode_config: EpisodeConfig, acoustics: AcousticsConfig,
           threads: int) -> None:
    episodes = episodes_for(episode_config, library)
    env = BatchEnv(episodes, library, n_envs=16, threads=threads,
                   config=EnvConfig(camera=False, acoustics=acoustics))
    names = ("waveform vs dry clip", "magnitude + target phase (paper)", "vs target as heard")
    scores = {pose: {name: [] for name in names} for pose in ("start", "target")}
    for first in range(0, len(episodes), env.n_envs):
        chunk = episodes[first:first + env.n_envs]
        chunk = chunk + [chunk[-1]] * (env.n_envs - len(chunk))
        at_target = [dataclasses.replace(e, start_node=e.target_node, start_heading=0) for e in chunk]
        for pose, batch in (("start", chunk), ("target", at_target)):
            obs, info = env.reset(episodes=batch)
            keep = slice(0, len(episodes[first:first + env.n_envs]))
            mono, dry = obs["audio"][keep].mean(axis=1), info["target_monaural"][keep]
            paper = rebuild_ground_truth_phase(np.abs(stft(mono)), dry)
            for name, value in zip(names, (si_sdr(mono, dry), si_sdr(paper, dry),
                                           si_sdr(mono, info["target_binaural"][keep].mean(axis=1)))):
                scores[pose][name].extend(np.atleast_1d(value).tolist())
    env.close()
    print(f"sanity: raw mixture (channel mean) SI-SDR as an estimate of the target, {len(episodes)} "
          f"{episode_config.task} {episode_config.sound_split} {SPLIT} episodes:")
    for name in names:
        start, target = np.mean(scores["start"][name]), np.mean(scores["target"][name])
        verdict = "higher at the target: yes" if target > start else "higher at the target: NO"
        print(f"  {name:34s} start pose {start:7.2f} dB   target node {target:7.2f} dB   {verdict}")


def in_process(target, *target_args):
    """``target(*target_args, queue)`` in a fresh (spawned) process; what it put on the queue."""
    context = multiprocessing.get_context("spawn")
    queue = context.Queue()
    worker = context.Process(target=target, args=(*target_args, queue))
    worker.start()
    while True:   # a worker that dies (e.g. on import) never puts: say so instead of waiting forever
        try:
            result = queue.get(timeout=1.0)
            break
        except Empty:
            if not worker.is_alive():
                raise RuntimeError(f"{target.__name__} worker exited with code {worker.exitcode}") from None
    worker.join()
    return result


def throughputs(args: argparse.Namespace, acoustics: AcousticsConfig, episode_config: EpisodeConfig) -> None:
    print(f"throughput ({args.steps} timed batch steps after 20 warm ones, uniformly random actions, "
          f"threads={args.threads}, render processes {args.render_processes}, pose cache {args.pose_cache}/slot, "
          f"RIR spectrum cache "
          f"{args.rir_spectra_mib:g} MiB, stored RIR spectra {'on' if args.stored_rir_spectra else 'off'}, "
          f"spectrogram observation {'on' if args.spectrogram else 'off'}, "
          f"RIR banks and views warm, {acoustics.rir_length} s RIRs):")
    rates = {}
    for camera in (False, True):
        for n_envs in (1, 16):
            runs = []
            for _ in range(args.repeats):
                # Other jobs on the cores change these figures by tens of percent: say how busy it was.
                load = os.getloadavg()[0]
                runs.append((*in_process(throughput, n_envs, camera, args.steps, args.threads,
                                         args.render_processes, args.pose_cache, args.rir_spectra_mib,
                                         args.stored_rir_spectra, args.spectrogram, acoustics, episode_config),
                             load))
            rate, cpu_ms, rss, hit_rate, spectra_rate, faults, read_mib, load = zip(*runs)
            rates[n_envs, camera] = np.median(rate)
            print(f"  {n_envs:2d} env(s), camera {'on ' if camera else 'off'}: "
                  f"{' / '.join(f'{r:.0f}' for r in rate)} env steps/s (aggregate; median {np.median(rate):.0f}, "
                  f"spread {min(rate):.0f}-{max(rate):.0f}), {min(cpu_ms):.2f}-{max(cpu_ms):.2f} ms CPU per "
                  f"env step, {max(faults):.1f} page faults per env step, "
                  f"{' / '.join(f'{x:.0f}' for x in read_mib)} MiB read from disk, pose-cache hits {100 * hit_rate[0]:.0f}%, RIR spectrum hits "
                  f"{100 * spectra_rate[0]:.0f}%, peak RSS {max(rss):.0f} MiB, load average before "
                  f"{' / '.join(f'{x:.1f}' for x in load)}")
    print(f"  16 batched / 1 env, camera on: {rates[16, True] / rates[1, True]:.1f}x (medians)")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--steps", type=int, default=200, help="timed batch steps per case")
    parser.add_argument("--threads", type=int, default=2, help="BatchEnv threads")
    parser.add_argument("--render-processes", type=int, default=0,
                        help="BatchEnv render processes in the throughput cases (try 1 with --threads 1)")
    parser.add_argument("--episodes", type=int, default=1000, help="test episodes (throughput and sanity)")
    parser.add_argument("--pose-cache", type=int, default=32,
                        help="BatchEnv pose-cache entries per slot (0: render every step)")
    parser.add_argument("--build-workers", type=int, default=2, help="processes building RIR banks")
    parser.add_argument("--fresh-build", action="store_true",
                        help="also time a from-scratch bank build of every scene (minutes)")
    parser.add_argument("--repeats", type=int, default=3, help="runs of each throughput case")
    parser.add_argument("--rir-length", type=float, default=None,
                        help="RIR length in s (default: the acoustics' default); other lengths build their banks")
    parser.add_argument("--rir-spectra-mib", type=float, default=0.0,
                        help="BatchEnv RIR spectrum cache (MiB, 0: off) in the throughput cases")
    parser.add_argument("--stored-rir-spectra", action="store_true",
                        help="BatchEnv(stored_rir_spectra=True): RIR spectra from files (~1 GiB per 32-node scene)")
    parser.add_argument("--only-fresh", action="store_true",
                        help="only the fresh-render figure (also runs against older BatchEnv versions)")
    parser.add_argument("--skip-sanity", action="store_true")
    parser.add_argument("--spectrogram", action="store_true",
                        help="EnvConfig(spectrogram=True): the log-magnitude observation (off by default, as here)")
    args = parser.parse_args()
    acoustics = AcousticsConfig() if args.rir_length is None else AcousticsConfig(rir_length=args.rir_length)
    library, which = open_library()
    print(f"sound library: {which}, {sum(len(library.infos(s)) for s in ('heard', 'unheard'))} clips")
    n_fft = convolution_length(clip_samples=DEFAULT_STFT.clip_samples, n_taps=acoustics.n_taps)
    build_banks(acoustics, args.build_workers, stored_spectra_fft=n_fft if args.stored_rir_spectra else None)
    if args.fresh_build:
        fresh_builds(args.build_workers)
    episode_config = EpisodeConfig(task="near_target", scene_split=SPLIT, sound_split="unheard",
                                   count=args.episodes)
    episodes_for(episode_config, library)   # cached once, before the workers read it
    print(availability_line())
    if not args.only_fresh:
        throughputs(args, acoustics, episode_config)
    load = os.getloadavg()[0]
    fresh, fft, n_fft = in_process(fresh_render, args.stored_rir_spectra, args.spectrogram, acoustics, episode_config)
    print(f"fresh render (16 envs rendering every step, camera on, 1 thread, stored RIR spectra "
          f"{'on' if args.stored_rir_spectra else 'off'}, best of 5 blocks, load "
          f"average {load:.1f}): {fresh:.2f} ms CPU per env step; its bare FFT work "
          f"{sum(fft.values()):.2f} ms (" + ", ".join(f"{k} {v:.2f}" for k, v in fft.items())
          + f"; convolution length {n_fft}), so {fresh - sum(fft.values()):.2f} ms is not FFT")
    if not (args.skip_sanity or args.only_fresh):
        sanity(library, episode_config, acoustics, args.threads)


if __name__ == "__main__":
    main()
