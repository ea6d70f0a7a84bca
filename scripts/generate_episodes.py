#!/usr/bin/env python3
"""Generate the versioned episode files (fixed seeds) into the data dir.

    python scripts/generate_episodes.py                      # test split: both tasks x heard/unheard, 1000 each
    python scripts/generate_episodes.py --scene-split train --count 20000 --sound-split heard
"""

import argparse
import itertools
import sys
import time

from m2h_ros.core.sounds.library import SoundLibrary, SoundLibraryConfig
from m2h_ros.core.world.episodes import SCENARIOS, SOUND_SPLITS, TASKS, EpisodeConfig, episode_path, episodes_for
from m2h_ros.errors import reports_errors


@reports_errors("generate_episodes")
def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--scene-split", default="test", choices=("train", "val", "test"))
    parser.add_argument("--task", choices=TASKS, action="append", help="default: both")
    parser.add_argument("--sound-split", choices=SOUND_SPLITS, action="append", help="default: both")
    parser.add_argument("--scenario", default="any", choices=tuple(SCENARIOS))
    parser.add_argument("--count", type=int, default=1000)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--small-library", action="store_true", help="use the --small sound library")
    args = parser.parse_args(argv)
    library = SoundLibrary.load(SoundLibraryConfig.small() if args.small_library else None)
    for task, sound_split in itertools.product(args.task or TASKS, args.sound_split or SOUND_SPLITS):
        config = EpisodeConfig(task=task, scene_split=args.scene_split, sound_split=sound_split,
                               scenario=args.scenario, count=args.count, seed=args.seed)
        started = time.perf_counter()
        episodes = episodes_for(config, library, progress=True)
        print(f"{len(episodes)} episodes {args.scene_split}/{task}/{sound_split}/{args.scenario} "
              f"in {time.perf_counter() - started:.1f} s -> {episode_path(config, library)}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
