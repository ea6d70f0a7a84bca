"""RIR bank figures: build time per scene and per source node, size on disk, gather + render time.

    python scripts/bench/acoustics.py [--split val] [--index 0] [--workers 2] [--envs 16] [--sources 2]

Builds into a fresh temporary bank folder unless --keep-cache is given (then data_dir() is used);
the HRTF and the other sources still come from data_dir().
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

import numpy as np

from m2h_ros.core.world.acoustics import (
    BAND_CENTRES,
    AcousticsConfig,
    mix,
    render_binaural,
    room_rt60,
)
from m2h_ros.core.world.rir_bank import RirBank
from m2h_ros.core.world.scene import SCENE_SPLITS, load_split


def _timed(fn, repeats: int) -> float:
    fn()  # warm-up (page cache, FFT plans)
    start = time.perf_counter()
    for _ in range(repeats):
        fn()
    return (time.perf_counter() - start) / repeats


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--split", choices=sorted(SCENE_SPLITS), default="val")
    parser.add_argument("--index", type=int, default=0)
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--envs", type=int, default=16)
    parser.add_argument("--sources", type=int, default=2)
    parser.add_argument("--storage-dtype", choices=("float16", "float32"), default="float32")
    parser.add_argument("--keep-cache", action="store_true")
    args = parser.parse_args(argv)

    if args.keep_cache:
        run(args, None)
        return
    with tempfile.TemporaryDirectory(prefix="m2h_bench_rir_") as root:
        run(args, Path(root))


def run(args: argparse.Namespace, cache_dir: Path | None) -> None:
    scene = load_split(args.split)[args.index]
    config = AcousticsConfig(storage_dtype=args.storage_dtype)
    n_nodes = len(scene.grid.positions)
    print(f"scene {scene.scene_id}: {len(scene.rooms)} rooms, {len(scene.walls)} walls, {n_nodes} nodes")
    k1 = int(np.argmin(np.abs(BAND_CENTRES - 1000)))
    for index, room in enumerate(scene.rooms):
        rt = room_rt60(scene, index)
        print(f"  {room.name}: Eyring RT60 at 1 kHz {rt[k1]:.2f} s (bands {np.round(rt, 2).tolist()})")

    bank = RirBank(scene, config, cache_dir=cache_dir)
    start = time.perf_counter()
    bank.build(workers=args.workers)
    build_s = time.perf_counter() - start
    print(f"bank build: {build_s:.1f} s with {args.workers} worker(s), "
          f"{build_s * args.workers / n_nodes:.2f} s of one core per source node")
    size = bank.size_on_disk()
    print(f"bank size on disk: {size / 2**20:.1f} MiB ({config.storage_dtype}, "
          f"{config.row_length} samples per source-receiver pair)")

    rng = np.random.default_rng(0)
    batch = args.envs * args.sources
    sources, receivers = rng.integers(0, n_nodes, batch), rng.integers(0, n_nodes, batch)
    headings = rng.integers(0, 4, batch)
    clips = rng.standard_normal((batch, config.sample_rate)).astype(np.float32)
    gather_s = _timed(lambda: bank.rirs(sources, receivers, headings), 50)
    rirs = bank.rirs(sources, receivers, headings)
    render_s = _timed(lambda: render_binaural(clips, rirs), 10)
    renders = render_binaural(clips, rirs).reshape(args.sources, args.envs, 2, -1)
    mix_s = _timed(lambda: mix(renders), 20)
    print(f"{args.envs} envs x {args.sources} sources: gather {gather_s * 1e3:.2f} ms, "
          f"render (1 s clips) {render_s * 1e3:.2f} ms, mix {mix_s * 1e3:.2f} ms, "
          f"gather/render ratio {gather_s / render_s:.2f}")


if __name__ == "__main__":
    main()
