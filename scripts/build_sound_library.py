#!/usr/bin/env python3
"""Build the sound library once: fetch the Debian sources (idempotent), cut the clips, write the cache.

    python scripts/build_sound_library.py            # the default library
    python scripts/build_sound_library.py --small    # the few-clip library the tests use
    python scripts/build_sound_library.py --write-index   # rewrite m2h_ros/core/sounds/library_index.json

The index (every clip's source file, offset and gain) is what lets the main job cut only the clips
of its episodes on a fresh machine (m2h_ros/core/sounds/partial.py); rewrite it whenever the default
library's configuration or material changes (a test checks it matches the configuration).

Prints where the library is, its size, clips per class and the build time.
"""

from __future__ import annotations

import argparse
import subprocess
import sys
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]

from m2h_ros.core.sounds import SPLITS, SoundLibrary, SoundLibraryConfig
from m2h_ros.core.sounds.partial import write_index
from m2h_ros.core.sounds.sources import sources_dir
from m2h_ros.errors import CacheError, reports_errors


@reports_errors("build_sound_library")
def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--small", action="store_true", help="few clips per class (tests)")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--force", action="store_true", help="rebuild even if the library exists")
    parser.add_argument("--write-index", action="store_true",
                        help="(default library) write the shipped index from the built library")
    args = parser.parse_args()
    config = SoundLibraryConfig.small(seed=args.seed) if args.small else SoundLibraryConfig(seed=args.seed)
    if args.write_index:
        if config != SoundLibraryConfig():
            parser.error("--write-index is for the default library (no --small, --seed 0)")
        print(f"index written to {write_index(SoundLibrary.load(config))}")
        return 0

    if not args.force:
        try:
            library = SoundLibrary.load(config)
        except CacheError:
            library = None
        if library is not None:
            print(f"sound library already built at {library.path}")
            return 0
    subprocess.run(["bash", str(REPO / "scripts" / "fetch_sound_sources.sh"), str(sources_dir())], check=True)
    started = time.perf_counter()
    library = SoundLibrary.build(config)
    elapsed = time.perf_counter() - started
    size = sum(p.stat().st_size for p in library.path.iterdir())
    print(f"sound library built at {library.path} in {elapsed:.1f} s, {size / 2**20:.1f} MiB")
    for category in library.categories:
        for cls in library.classes_of(category):
            counts = ", ".join(f"{split} {len(library.clips(split, cls=cls))}" for split in SPLITS)
            print(f"  {category:10s} {cls:14s} {counts}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
