"""Simulator throughput: environment steps/s for 1 and 16 batched envs, with and without camera.

    python scripts/bench/sim.py [--steps 200] [--threads 2] [--episodes 1000] [--build-workers 2]
                                [--fresh-build]

Uses the test split's default scenes and the default acoustics; builds (or reuses) their RIR banks
under data_dir() first and reports their size per scene (and the build time of what was missing);
--fresh-build also times a full build of every scene into a temporary cache with
scripts/bench/acoustics.py. Sound library: the full default
one if it is built, else the --small one (built if missing); the output says which. Each throughput
case runs in a fresh process with warm caches and reports its peak RSS. Last, the sanity figure:
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

import numpy as np

from m2h_ros.core.audio.metrics import si_sdr
from m2h_ros.core.audio.stft import rebuild_ground_truth_phase, stft
from m2h_ros.core.sounds.library import SoundLibrary, SoundLibraryConfig
from m2h_ros.core.world.acoustics import AcousticsConfig
from m2h_ros.core.world.env import BatchEnv, EnvConfig
from m2h_ros.core.world.episodes import EpisodeConfig, episodes_for
from m2h_ros.core.world.rir_bank import RirBank
from m2h_ros.core.world.scene import load_split
from m2h_ros.errors import CacheError

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


def build_banks(acoustics: AcousticsConfig, workers: int) -> None:
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


def throughput(n_envs: int, camera: bool, steps: int, threads: int, pose_cache: int,
               acoustics: AcousticsConfig, episode_config: EpisodeConfig, queue) -> None:
    """Runs in a fresh process: steps/s of one BatchEnv with warm caches, and the peak RSS."""
    library, _ = open_library()
    episodes = episodes_for(episode_config, library)
    env = BatchEnv(episodes, library, n_envs=n_envs, threads=threads, pose_cache=pose_cache,
                   config=EnvConfig(camera=camera, acoustics=acoustics))
    env.prepare(progress=False)
    env.reset()
    actions = np.random.default_rng(0).integers(4, size=(steps + 20, n_envs))
    for batch in actions[:20]:
        env.step(batch)
    wall, cpu = time.perf_counter(), time.process_time()
    for batch in actions[20:]:
        env.step(batch)
    wall, cpu = time.perf_counter() - wall, time.process_time() - cpu
    env.close()
    queue.put((n_envs * steps / wall, 1e3 * cpu / (n_envs * steps),
               resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024, env.pose_cache_hit_rate))


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


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--steps", type=int, default=200, help="timed batch steps per case")
    parser.add_argument("--threads", type=int, default=2, help="BatchEnv threads")
    parser.add_argument("--episodes", type=int, default=1000, help="test episodes (throughput and sanity)")
    parser.add_argument("--pose-cache", type=int, default=32,
                        help="BatchEnv pose-cache entries per slot (0: render every step)")
    parser.add_argument("--build-workers", type=int, default=2, help="processes building RIR banks")
    parser.add_argument("--fresh-build", action="store_true",
                        help="also time a from-scratch bank build of every scene (minutes)")
    parser.add_argument("--skip-sanity", action="store_true")
    args = parser.parse_args()
    acoustics = AcousticsConfig()
    library, which = open_library()
    print(f"sound library: {which}, {sum(len(library.infos(s)) for s in ('heard', 'unheard'))} clips")
    build_banks(acoustics, args.build_workers)
    if args.fresh_build:
        fresh_builds(args.build_workers)
    episode_config = EpisodeConfig(task="near_target", scene_split=SPLIT, sound_split="unheard",
                                   count=args.episodes)
    episodes_for(episode_config, library)   # cached once, before the workers read it
    context = multiprocessing.get_context("spawn")
    # Other jobs on the 2 cores change these figures by tens of percent: say how busy the machine was.
    print(f"load average before the runs: {', '.join(f'{x:.2f}' for x in os.getloadavg())}")
    print(f"throughput ({args.steps} timed batch steps after 20 warm ones, uniformly random actions, "
          f"threads={args.threads}, pose cache {args.pose_cache}/slot, RIR banks and views warm):")
    rates = {}
    for camera in (False, True):
        for n_envs in (1, 16):
            queue = context.Queue()
            worker = context.Process(target=throughput, args=(n_envs, camera, args.steps, args.threads,
                                                              args.pose_cache, acoustics, episode_config,
                                                              queue))
            worker.start()
            rate, cpu_ms, rss, hit_rate = queue.get()
            worker.join()
            rates[n_envs, camera] = rate
            print(f"  {n_envs:2d} env(s), camera {'on ' if camera else 'off'}: {rate:8.0f} env steps/s "
                  f"(aggregate), {cpu_ms:.2f} ms CPU per env step, pose-cache hits {100 * hit_rate:.0f}%, "
                  f"peak RSS {rss:.0f} MiB")
    print(f"  16 batched / 1 env, camera on: {rates[16, True] / rates[1, True]:.1f}x")
    if not args.skip_sanity:
        sanity(library, episode_config, acoustics, args.threads)


if __name__ == "__main__":
    main()
