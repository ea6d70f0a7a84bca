"""Build the binaural RIR banks of a scene split into the on-disk cache (data_dir()/rir_banks).

    python scripts/build_rir_banks.py --split train [--scenes 3] [--workers 2] [--head free_field:0.2]
"""

from __future__ import annotations

import argparse
import time
import sys

from m2h_ros.core.world.acoustics import AcousticsConfig
from m2h_ros.core.world.hrtf import HEAD_HELP, KEMAR
from m2h_ros.core.world.rir_bank import RirBank
from m2h_ros.core.world.scene import PRESETS, SCENE_SPLITS, load_split
from m2h_ros.errors import reports_errors


@reports_errors("build_rir_banks")
def main(argv: list[str] | None = None) -> int | None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--split", choices=sorted(SCENE_SPLITS), required=True)
    parser.add_argument("--scenes", type=int, default=None, help="only the first N scenes")
    parser.add_argument("--preset", choices=sorted(PRESETS), default="default")
    parser.add_argument("--workers", type=int, default=2, help="processes over source nodes")
    parser.add_argument("--head", default=KEMAR, help=HEAD_HELP)
    args = parser.parse_args(argv)

    scenes = load_split(args.split, preset=args.preset)[: args.scenes]
    config = AcousticsConfig(head=args.head)
    for scene in scenes:
        start = time.perf_counter()
        bank = RirBank(scene, config)
        bank.build(workers=args.workers)
        print(f"{scene.scene_id}: {len(scene.grid.positions)} nodes, "
              f"{bank.size_on_disk() / 2**20:.1f} MiB in {time.perf_counter() - start:.1f} s -> {bank.directory}")


if __name__ == "__main__":
    sys.exit(main())
