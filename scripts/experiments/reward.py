#!/usr/bin/env python3
"""Experiment 6 of the supplementary material: pi^Q's reward, NMSE vs SNR vs SI-SDR improvement.

    python scripts/experiments/reward.py --runs runs/reward/nmse,runs/reward/snr,runs/reward/si_sdr
        [--sound-split heard,unheard] [--count 100] [--chunk 50] [--workers 2] [--address ADDR]
        [--seed 0] [--out runs/experiments/reward/stage2]

Train the runs first, one per reward, with the same seed and budget (docs/design/experiments.md):

    python scripts/train_policy.py --kind quality --frozen-refiner --updates 250 --episodes 10000 --seed 0 \\
        --threads 1 --quality-reward si_sdr --out runs/reward/si_sdr

Each run's pi^Q (its policy.pt) and Stand In-Place play the same near-target test episodes; the report
(results.md / .csv / .json, si_sdr_vs_step.png, training_curves.png) gives final-step SI-SDR with 95% CI,
each pi^Q's paired difference to Stand In-Place and to the first run's pi^Q, and each run's training
time: the supplementary's question is which measure trains the better pi^Q, and at what cost.
"""

import argparse
import json
import os
import shlex
import sys
import time
from pathlib import Path

os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")

from m2h_ros.core.results import (markdown_table, paired_differences, paired_table, summarize,  # noqa: E402
                                  write_results)
from m2h_ros.errors import M2HError  # noqa: E402
from m2h_ros.experiments import reward  # noqa: E402
from m2h_ros.machine import load_averages  # noqa: E402
from m2h_ros.paths import RUNS_DIR, repo_relative  # noqa: E402


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--runs", required=True, help="comma-separated pi^Q run directories, one per reward")
    parser.add_argument("--sound-split", default="heard,unheard")
    parser.add_argument("--count", type=int, default=100, help="near-target test episodes per split")
    parser.add_argument("--chunk", type=int, default=50, help="episodes per Ray job")
    parser.add_argument("--workers", type=int, default=2, help="local Ray CPUs (ignored with --address)")
    parser.add_argument("--address", help="an existing Ray cluster")
    parser.add_argument("--seed", type=int, default=0, help="seed of pi^Q's sampled actions")
    parser.add_argument("--out", type=Path, default=RUNS_DIR / "experiments" / "reward",
                        help="output folder (default: %(default)s)")
    parser.add_argument("--no-progress", action="store_true")
    args = parser.parse_args()
    command = shlex.join(["python", repo_relative(__file__), *sys.argv[1:]])
    started = time.perf_counter()
    try:
        runs = [reward.load_run(Path(d)) for d in args.runs.split(",") if d]
        if not runs:
            raise M2HError("no --runs given")
        reward.check_comparable(runs)
        splits = args.sound_split.split(",")
        jobs = reward.reward_jobs(runs, sound_splits=splits, count=args.count, chunk=args.chunk, seed=args.seed)
        results = reward.run_reward_jobs(jobs, workers=args.workers, address=args.address,
                                         progress=not args.no_progress)
    except (M2HError, ValueError) as exc:
        print(f"reward.py: error: {exc}", file=sys.stderr)
        return 2
    meta = {"command": command, "task": "near_target", "sound_splits": splits, "count_per_split": args.count,
            "controller_seed": args.seed, "workers": args.address or args.workers,
            "runs": reward.describe_runs(runs), "wall_seconds": round(time.perf_counter() - started, 1),
            "load_average": load_averages()}
    paths = write_results(results, args.out, title=f"pi^Q by reward: near-target test episodes, {' + '.join(splits)}",
                          meta=meta, command=command, reference=reward.REFERENCE,
                          setup=f"separator {runs[0].config['separator'] or 'shipped'}; runs "
                                + ", ".join(f"`{repo_relative(r.directory)}`" for r in runs))
    paths["curves"] = reward.plot_training(runs, args.out / "training_curves.png")
    # The rewards against each other: every run's pi^Q minus the first run's, episode by episode.
    versus = [r for r in paired_differences(results, reference=runs[0].label) if r["controller"] != reward.REFERENCE]
    with paths["markdown"].open("a") as stream:
        if versus:
            stream.write(f"\nFinal-step SI-SDR (dB, GT phase) minus {runs[0].label}'s on the same episodes:\n\n"
                         f"{paired_table(versus)}")
        stream.write(f"\nTraining (each run's policy.pt metadata and log.csv):\n\n{reward.timing_table(runs)}"
                     "\nTraining curves: training_curves.png.\n")
    document = json.loads(paths["json"].read_text())
    paths["json"].write_text(json.dumps({**document, "paired_vs_first_run": versus}, indent=1))
    print(markdown_table(summarize(results)))
    print(paired_table(paired_differences(results, reference=reward.REFERENCE)))
    print(paired_table(versus))
    print(reward.timing_table(runs))
    print(", ".join(f"{kind}: {path}" for kind, path in paths.items()))
    return 0


if __name__ == "__main__":
    sys.exit(main())
