#!/usr/bin/env python3
"""Where each controller's walk ends relative to the target, from results already written (no episode is
played again): mean geodesic distance to the target's node at the start, halfway and at the end, and the
share of episodes that end on it or were on it at some step (``m2h_ros/experiments/reach.py``).

    python scripts/experiments/reach.py runs/near_test/results.json [--reference stand_in_place] [--out reach.md] [--png reach.png]
    python scripts/experiments/reach.py shipped/results.json candidate/results.json --tags shipped,candidate

Results of ``scripts/evaluate.py``, the evaluator node, ``m2h-eval`` or the experiments, for episodes made
with the default settings of their split, task, sound split and scenario (the episode ids name those).
"""

from __future__ import annotations

import argparse
import dataclasses
import shlex
import sys
from pathlib import Path

from m2h_ros.core.results import read_results
from m2h_ros.core.sounds.library import SoundLibrary
from m2h_ros.core.world.episodes import EpisodeConfig, episodes_for
from m2h_ros.errors import ConfigError, reports_errors
from m2h_ros.experiments.reach import gain_by_reach, gain_markdown, plot_reach, reach_markdown, reach_table


@reports_errors("reach")
def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("results", nargs="+", type=Path, help="results.json files")
    parser.add_argument("--tags", default="", help="one name per results file, comma-separated: its controllers "
                        "become <controller>:<tag> (runs of one controller name apart)")
    parser.add_argument("--reference", default="", help="also the final-step SI-SDR gain over this controller "
                        "(on the same episodes) of the walks that end on the target, left it, or never reached it")
    parser.add_argument("--out", type=Path, help="also write the table to this Markdown file")
    parser.add_argument("--png", type=Path, help="also plot the mean distance to the target vs step here")
    args = parser.parse_args(argv)
    command = shlex.join(["python", "scripts/experiments/reach.py", *(sys.argv[1:] if argv is None else argv)])
    tags = args.tags.split(",") if args.tags else [""] * len(args.results)
    if len(tags) != len(args.results):
        raise ConfigError(f"--tags names {len(tags)} runs for {len(args.results)} results files")
    results = [dataclasses.replace(r, controller=f"{r.controller}:{tag}" if tag else r.controller)
               for path, tag in zip(args.results, tags, strict=True) for r in read_results(path)]
    library, episodes = SoundLibrary.load(), {}
    for prefix in sorted({r.episode_id.rsplit("/", 1)[0] for r in results}):
        parts = prefix.split("/")
        if len(parts) != 4:
            raise ConfigError(f"episode ids like {prefix!r}/... do not name split/task/sound split/scenario")
        scene_split, task, sound_split, scenario = parts
        config = EpisodeConfig(task=task, scene_split=scene_split, sound_split=sound_split, scenario=scenario)
        episodes.update((e.episode_id, e) for e in episodes_for(config, library))
    table = reach_markdown(reach_table(results, episodes))
    if args.reference:
        table += "\n\n" + gain_markdown(gain_by_reach(results, episodes, reference=args.reference),
                                         reference=args.reference)
    if args.png:
        print(f"plot: {plot_reach(results, episodes, args.png)}")
    print(table)
    if args.out:
        args.out.parent.mkdir(parents=True, exist_ok=True)
        args.out.write_text(f"# Where the walks end\n\nCommand: `{command}`\n\nGeodesic metres to the target's node "
                            f"(recorded actions replayed on the navigation grid), mean over episodes.\n\n{table}\n")
        print(f"markdown: {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
