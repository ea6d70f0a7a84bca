#!/usr/bin/env python3
"""Diagnostic: how predictable the approach teacher's action is from the ILD of what the policy hears.

    python scripts/experiments/teacher_probe.py [--task near_target] [--rollouts 60] [--seed 5]
        [--out DIR]

Rollouts of an untrained policy on training episodes (16 slots x 20 steps each, camera off), then a
linear and a one-hidden-layer probe from the ILD spectrum of the separated binaural estimate to the
teacher's distribution (``m2h_ros/training/teacher_probe.py``). Writes ``results.md`` and
``results.json``.
"""

import argparse
import json
import os
import shlex
import sys
import time
from pathlib import Path

os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")

from m2h_ros.core.sounds.library import SoundLibrary  # noqa: E402
from m2h_ros.core.world.env import EnvConfig  # noqa: E402
from m2h_ros.core.world.episodes import TASKS, EpisodeConfig  # noqa: E402
from m2h_ros.errors import ConfigError, reports_errors  # noqa: E402
from m2h_ros.machine import load_averages  # noqa: E402
from m2h_ros.training.teacher_probe import collect_probe_data, fit_probe, ild_sign_accuracy  # noqa: E402
from m2h_ros.paths import RUNS_DIR  # noqa: E402
from m2h_ros.training.ppo import PPOTrainer  # noqa: E402
from m2h_ros.training.ppo_config import TRAIN_FAR_STEPS, PPOConfig  # noqa: E402


@reports_errors("teacher_probe")
def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--task", choices=TASKS, default="near_target")
    parser.add_argument("--rollouts", type=int, default=60)
    parser.add_argument("--seed", type=int, default=5, help="episode draw and probe seed")
    parser.add_argument("--out", type=Path, help="default runs/teacher_probe_<task>")
    args = parser.parse_args(argv)
    command = shlex.join(["python", "scripts/experiments/teacher_probe.py", *(sys.argv[1:] if argv is None else argv)])
    out = args.out or RUNS_DIR / f"teacher_probe_{args.task}"
    started = time.perf_counter()
    if args.rollouts < 2:
        raise ConfigError("--rollouts must be >= 2 (a fifth of the states is held out)")
    far = args.task == "far_target"
    episodes = EpisodeConfig(task=args.task, scene_split="train", sound_split="heard", count=3000, seed=args.seed,
                             max_steps=TRAIN_FAR_STEPS if far else None)
    config = PPOConfig(kind="navigation" if far else "quality", episodes=episodes, env=EnvConfig(camera=False),
                       threads=1, teacher_coef=1.0, train_refiner=False, seed=args.seed)
    trainer = PPOTrainer(config, SoundLibrary.load(), out_dir=out, progress=False)
    try:
        data = collect_probe_data(trainer, args.rollouts)
    finally:
        trainer.env.close()
    fits = {f"{'linear' if hidden == 0 else f'mlp{hidden}'}": fit_probe(data, hidden=hidden, seed=args.seed)
            for hidden in (0, 128)}
    accuracy, turning = ild_sign_accuracy(data)
    report = {"command": command, "task": args.task, "states": len(data.ild), "fits": fits,
              "ild_sign_accuracy": accuracy, "turning_states": turning,
              "wall_seconds": round(time.perf_counter() - started, 1),
              "load_average": load_averages()}
    lines = [f"# Approach teacher probe, {args.task} training episodes", "", f"Command: `{command}`", "",
             f"{len(data.ild)} states of an untrained policy's rollouts (a fifth held out). Cross-entropy to the "
             "teacher's distribution on the held-out states (nats; lower is better):", "",
             "| probe from the ILD spectrum | held-out CE | label prior's CE | teacher's own entropy |", "|---|---|---|---|"]
    lines += [f"| {name} | {fit['probe_ce']:.3f} | {fit['prior_ce']:.3f} | {fit['teacher_entropy']:.3f} |"
              for name, fit in fits.items()]
    lines += ["", f"Where the teacher turns ({turning} states), the mean ILD's sign names its turn in "
              f"{100 * accuracy:.1f}% of them.", ""]
    out.mkdir(parents=True, exist_ok=True)
    (out / "results.md").write_text("\n".join(lines))
    (out / "results.json").write_text(json.dumps(report, indent=2) + "\n")
    print("\n".join(lines))
    print(f"{report['wall_seconds']} s; {out / 'results.md'}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
