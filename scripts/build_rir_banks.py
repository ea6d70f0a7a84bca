"""Build the binaural RIR banks of a scene split or an imported world into the on-disk cache (data_dir()/rir_banks).

    python scripts/build_rir_banks.py --split train [--scenes 3] [--workers 2] [--head free_field:0.2]
    python scripts/build_rir_banks.py --world map:PATH/map.yaml [--workers 2] [--ray local|ADDRESS]

Source nodes are computed by --workers local processes, or with --ray as Ray tasks: ``local`` starts a
Ray instance of --workers CPUs on this machine, any other value is a running cluster's address (its
nodes need m2h_ros and the head's HRTF). This process writes every file, so an interrupted build
keeps what it finished and the next run computes only the missing source nodes; the files are the
same bit for bit however they were computed.
"""

from __future__ import annotations

import argparse
import sys
import time

from m2h_ros.core.world.acoustics import BACKENDS, BACKEND_HELP, AcousticsConfig
from m2h_ros.core.world.hrtf import HEAD_HELP, KEMAR
from m2h_ros.core.world.rir_bank import RirBank
from m2h_ros.core.world.scene import PRESETS, SCENE_SPLITS, load_split
from m2h_ros.core.world.worlds import load_world
from m2h_ros.errors import reports_errors


@reports_errors("build_rir_banks")
def main(argv: list[str] | None = None) -> int | None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    which = parser.add_mutually_exclusive_group(required=True)
    which.add_argument("--split", choices=sorted(SCENE_SPLITS))
    which.add_argument("--world", help="an imported world: map:PATH/map.yaml or mesh:PATH")
    parser.add_argument("--scenes", type=int, default=None, help="only the first N scenes of --split")
    parser.add_argument("--preset", choices=sorted(PRESETS), default="default")
    parser.add_argument("--workers", type=int, default=2, help="processes over source nodes (CPUs of --ray local)")
    parser.add_argument("--ray", metavar="ADDRESS", default=None,
                        help="run the source nodes as Ray tasks: 'local', or a running cluster's address")
    parser.add_argument("--head", default=KEMAR, help=HEAD_HELP)
    parser.add_argument("--acoustics-backend", default="project", choices=BACKENDS, help=BACKEND_HELP)
    args = parser.parse_args(argv)

    scenes = [load_world(args.world)] if args.world else load_split(args.split, preset=args.preset)[: args.scenes]
    config = AcousticsConfig(head=args.head, backend=args.acoustics_backend)
    for scene in scenes:
        start = time.perf_counter()
        bank = RirBank(scene, config)
        computed = bank.build(workers=args.workers, ray_address=args.ray)
        print(f"{scene.scene_id}: {len(scene.grid.positions)} nodes ({computed} computed now), "
              f"{bank.size_on_disk() / 2**20:.1f} MiB in {time.perf_counter() - start:.1f} s -> {bank.directory}")


if __name__ == "__main__":
    sys.exit(main())
