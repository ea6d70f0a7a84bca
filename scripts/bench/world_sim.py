"""Simulator throughput in an imported world against generated ones: env steps/s of 16 batched envs in
the example apartment (a nav2 map) and in generated scenes, measured as scripts/bench/sim.py measures
them (``throughput``: a fresh process per run, banks and views warm, uniformly random actions), runs
of the two interleaved; their ratio (target: the imported world within 20 % of the generated ones) and
the imported world's peak RSS with its bank memory-mapped (target: <= 2 GB).

    python scripts/bench/world_sim.py [--steps 200] [--repeats 3] [--threads 2] [--split train]
                                      [--default-acoustics] [--noise 0.3] [--scale 1.25]

The apartment is written as ``scripts/draw_apartment_map.py`` writes it (--noise, seed 0) into
data_dir()/bench_worlds/ (the episodes name it by its path). The generated worlds are the scenes of
--split (``train``: the generated scenes with the most nodes; their node counts are printed). The
acoustics are the tests' fast settings (0.25 s RIRs, image sources to order 2, no tail), so both
banks build in a minute; --default-acoustics uses ``AcousticsConfig()`` (1 s RIRs, a bank four times
the size: minutes to build, and the RSS figure for the default engine). --scale 1.25 --noise 0 plays the
~154 m^2 home of scripts/bench/world_bank.py instead (139 nodes, a 3.2 GiB bank with the default acoustics:
the RSS target's home).
"""

from __future__ import annotations

import argparse
import importlib
import os
import sys
from pathlib import Path

import numpy as np

from m2h_ros.core.world.acoustics import AcousticsConfig
from m2h_ros.core.world.episodes import EpisodeConfig, episodes_for
from m2h_ros.core.world.rir_bank import RirBank
from m2h_ros.core.world.ros_map import write_ros_map
from m2h_ros.core.world.sample_worlds import apartment_grid, write_home_map
from m2h_ros.core.world.scene import SCENE_SPLITS
from m2h_ros.core.world.worlds import worlds_of
from m2h_ros.machine import availability_line, load_average
from m2h_ros.paths import data_dir

FAST_ACOUSTICS = AcousticsConfig(rir_length=0.25, early_length=0.064, ism_max_order=2, tail=False)
RATIO_TARGET = 0.8
RSS_TARGET_MIB = 2000 / 1.048576  # 2 GB


def sim_bench():
    """scripts/bench/sim.py as a module: its throughput measurement, fresh-process runner and library.
    Imported by name from its folder on sys.path, which spawned processes inherit, so that they can
    unpickle its functions."""
    sys.path.insert(0, str(Path(__file__).resolve().parent))
    return importlib.import_module("sim")


def apartment_spec(noise: float, scale: float | None) -> str:
    """``map:PATH`` of the example apartment (or with --scale, the home of scripts/bench/world_bank.py),
    written once per noise level and scale."""
    if scale is None:
        path = data_dir() / "bench_worlds" / f"apartment_noise{noise:g}" / "map.yaml"
        if not path.exists():
            write_ros_map(path, apartment_grid(resolution=0.05, noise=noise))
    else:
        path = data_dir() / "bench_worlds" / f"home_x{scale:g}_noise{noise:g}" / "map.yaml"
        if not path.exists():
            write_home_map(path.parent, scale=scale, noise=noise)
    return f"map:{path}"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--steps", type=int, default=200, help="timed batch steps per run")
    parser.add_argument("--repeats", type=int, default=3, help="runs per world and camera setting")
    parser.add_argument("--threads", type=int, default=2, help="BatchEnv threads")
    parser.add_argument("--envs", type=int, default=16, help="batched envs")
    parser.add_argument("--episodes", type=int, default=200, help="near-target episodes per world")
    parser.add_argument("--split", choices=sorted(SCENE_SPLITS), default="train", help="the generated worlds")
    parser.add_argument("--noise", type=float, default=0.3, help="the apartment map's SLAM look")
    parser.add_argument("--scale", type=float, default=None,
                        help="the apartment's lengths times this (1.25: the ~154 m^2 home of world_bank.py)")
    parser.add_argument("--build-workers", type=int, default=2, help="processes building RIR banks")
    parser.add_argument("--default-acoustics", action="store_true", help="AcousticsConfig() instead of the fast one")
    args = parser.parse_args()
    sim = sim_bench()
    acoustics = AcousticsConfig() if args.default_acoustics else FAST_ACOUSTICS
    library, which = sim.open_library()
    print(f"sound library: {which}; acoustics: {acoustics.rir_length} s RIRs, image sources to order "
          f"{acoustics.ism_max_order}, tail {'on' if acoustics.tail else 'off'}")
    worlds = {"imported": apartment_spec(args.noise, args.scale), "generated": args.split}
    configs = {}
    for kind, spec in worlds.items():
        scenes = worlds_of(spec)
        for scene in scenes:
            RirBank(scene, acoustics, progress=False).build(workers=args.build_workers, progress=True)
        sizes = [RirBank(scene, acoustics, progress=False).size_on_disk() / 2**20 for scene in scenes]
        print(f"{kind}: {spec if kind == 'generated' else 'the apartment, ' + spec}: {len(scenes)} world(s) of "
              f"{', '.join(str(s.grid.n_nodes) for s in scenes)} nodes; banks {', '.join(f'{m:.0f}' for m in sizes)} MiB")
        configs[kind] = EpisodeConfig(task="near_target", scene_split=spec, sound_split="unheard",
                                      count=args.episodes)
        episodes_for(configs[kind], library)   # cached once, before the runs read it
    print(availability_line())
    print(f"{args.envs} envs, {args.steps} timed batch steps after 20 warm ones, threads={args.threads}, pose cache 32, "
          f"runs of the two worlds interleaved:")
    for camera in (False, True):
        runs = {kind: [] for kind in worlds}
        for _ in range(args.repeats):
            for kind in worlds:
                load = os.getloadavg()[0]
                rate, cpu_ms, rss, *_ = sim.in_process(sim.throughput, args.envs, camera, args.steps, args.threads,
                                                       0, 32, 0.0, False, False, acoustics, configs[kind])
                runs[kind].append((rate, cpu_ms, rss, load))
        for kind, values in runs.items():
            rate, cpu_ms, rss, load = zip(*values)
            print(f"  camera {'on ' if camera else 'off'}, {kind:9s}: {' / '.join(f'{r:.0f}' for r in rate)} env steps/s "
                  f"(min {min(rate):.0f} / median {np.median(rate):.0f} / max {max(rate):.0f}), "
                  f"{np.median(cpu_ms):.2f} ms CPU per env step, peak RSS {max(rss):.0f} MiB, load average before "
                  f"{' / '.join(f'{x:.1f}' for x in load)}")
        ratio = np.median([r[0] for r in runs["imported"]]) / np.median([r[0] for r in runs["generated"]])
        rss = max(r[2] for r in runs["imported"])
        print(f"  camera {'on ' if camera else 'off'}: imported / generated {ratio:.2f} (medians; target >= "
              f"{RATIO_TARGET}: {'met' if ratio >= RATIO_TARGET else 'MISSED'}); imported peak RSS {rss:.0f} MiB "
              f"(target <= {RSS_TARGET_MIB:.0f} MiB: {'met' if rss <= RSS_TARGET_MIB else 'MISSED'})")
    print(f"load average after: {load_average()}")


if __name__ == "__main__":
    main()
