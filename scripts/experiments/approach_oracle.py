#!/usr/bin/env python3
"""Diagnostic: what walking to the target's node gains over standing still, with ground-truth knowledge.

    python scripts/experiments/approach_oracle.py [--task near_target] [--sound-split heard,unheard]
        [--count 500] [--threads 2] [--checkpoint SEPARATOR] [--hold stand,turn] [--out runs/diagnostics/approach_oracle]

Plays Stand In-Place and :class:`m2h_ros.experiments.oracle.ApproachOracle` (a shortest path to the
target's node, read from the episode file, then holding there) on the same test episodes with the
shipped separator (or --checkpoint), and writes the paper-style table with the oracle's paired difference to Stand
In-Place (``--hold``: one oracle per way of holding at the target, standing still or turning as
pi^Q must). It bounds what a policy that learns to approach the target can gain here: the issue's
near-target target for Move2Hear is Stand In-Place + 1.5 dB.
"""

import argparse
import os
import shlex
import sys
import time
from pathlib import Path

os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")

import torch  # noqa: E402

from m2h_ros.agents.registry import make_controller  # noqa: E402
from m2h_ros.agents.rollout import evaluate_controller  # noqa: E402
from m2h_ros.core.results import markdown_table, paired_differences, paired_table, summarize, write_results  # noqa: E402
from m2h_ros.core.sounds.library import SoundLibrary  # noqa: E402
from m2h_ros.core.world.env import EnvConfig  # noqa: E402
from m2h_ros.core.world.episodes import SOUND_SPLITS, TASKS, EpisodeConfig, episodes_for  # noqa: E402
from m2h_ros.errors import ConfigError, reports_errors  # noqa: E402
from m2h_ros.experiments.oracle import ApproachOracle  # noqa: E402
from m2h_ros.machine import load_averages  # noqa: E402
from m2h_ros.models.checkpoint import DEFAULT_SEPARATOR_CHECKPOINT, load_separator  # noqa: E402
from m2h_ros.models.runner import SeparatorRunner  # noqa: E402
from m2h_ros.paths import RUNS_DIR, file_label, repo_relative  # noqa: E402

REFERENCE = "stand_in_place"


@reports_errors("approach_oracle")
def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--task", choices=TASKS, default="near_target")
    parser.add_argument("--sound-split", default="heard,unheard")
    parser.add_argument("--count", type=int, default=500, help="first test episodes per sound split")
    parser.add_argument("--slots", type=int, default=16)
    parser.add_argument("--threads", type=int, default=2)
    parser.add_argument("--checkpoint", type=Path, default=DEFAULT_SEPARATOR_CHECKPOINT, help="separator checkpoint")
    parser.add_argument("--hold", default="stand", help="how the oracle holds on the target's node, comma-separated: "
                        "stand (Stop, as Stand In-Place) and/or turn (TurnLeft each step, as pi^Q can)")
    parser.add_argument("--out", type=Path, default=RUNS_DIR / "diagnostics" / "approach_oracle",
                        help="output folder (default: %(default)s)")
    parser.add_argument("--no-progress", action="store_true")
    args = parser.parse_args(argv)
    command = shlex.join(["python", "scripts/experiments/approach_oracle.py", *(sys.argv[1:] if argv is None else argv)])
    started = time.perf_counter()
    splits = args.sound_split.split(",")
    if any(s not in SOUND_SPLITS for s in splits) or args.count < 1 or args.slots < 1 or args.threads < 1:
        raise ConfigError(f"--sound-split must name {SOUND_SPLITS}; --count, --slots, --threads >= 1")
    holds = args.hold.split(",")
    if any(h not in ApproachOracle.HOLDS for h in holds):
        raise ConfigError(f"--hold must name {sorted(ApproachOracle.HOLDS)}")
    torch.set_num_threads(args.threads)
    library, loaded = SoundLibrary.load(), load_separator(args.checkpoint)
    episodes = [e for split in splits for e in episodes_for(
        EpisodeConfig(task=args.task, scene_split="test", sound_split=split), library)[:args.count]]
    slots = min(args.slots, len(episodes))
    results = []
    oracles = [ApproachOracle(slots, episodes=episodes, hold=hold) for hold in holds]
    for controller in (make_controller(REFERENCE, slots), *oracles):
        results += evaluate_controller(controller, SeparatorRunner(loaded, slots), episodes, library,
                                       env_config=EnvConfig(camera=False), threads=args.threads,
                                       progress=not args.no_progress)
    meta = {"command": command, "checkpoint": repo_relative(loaded.path), "task": args.task,
            "sound_splits": splits, "count_per_split": args.count, "threads": args.threads,
            "wall_seconds": round(time.perf_counter() - started, 1),
            "load_average": load_averages()}
    paths = write_results(results, args.out, title=f"Approach oracle vs Stand In-Place, {args.task} test episodes",
                          meta=meta, command=command, setup=f"separator {file_label(loaded.path)}",
                          reference=REFERENCE)
    print(markdown_table(summarize(results)))
    print(f"final-step SI-SDR (GT phase) minus {REFERENCE}'s, same episodes:")
    print(paired_table(paired_differences(results, reference=REFERENCE)))
    oracle = [r for r in results if r.controller == oracles[0].name]
    print(f"oracle path: {sum(r.path_length for r in oracle) / len(oracle):.2f} m on average "
          f"(shortest {sum(r.shortest_path for r in oracle) / len(oracle):.2f} m)")
    print(f"{len(results)} episodes in {meta['wall_seconds']} s; " + ", ".join(f"{k}: {v}" for k, v in paths.items()))
    return 0


if __name__ == "__main__":
    sys.exit(main())
