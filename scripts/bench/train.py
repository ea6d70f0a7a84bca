"""PPO training throughput: environment steps/s of the compact policy on the test scenes, and the share
of an update's wall time spent in the simulator, the separator (f^B, f^M, f^R inference), acting
(policy inputs + forward), the PPO update and the f^R update (quality only).

    python scripts/bench/train.py [--kind quality] [--updates 4] [--repeats 3] [--n-envs 16] [--threads 2]
    python scripts/bench/train.py --shipped-quality    # the shipped pi^Q's recipe (params/recipes/policy_quality.args)

Each repeat is a fresh trainer (16 slots x 20 steps per update, camera on, the shipped compact
separator, the full sound library) on near-target (far-target for navigation kinds) test episodes,
whose RIR banks must be built (the same banks evaluation builds). RIR banks and camera
views are loaded before timing and the first update is a warm-up; the figure is the median over the
remaining updates, with the process's CPU time per env step (all threads: what the steps cost
whatever the load), and the share of separated observations whose f^B / f^M outputs the rollout
reused (a slot back at a pose it has heard this episode: ``SeparatorRunner``'s pose cache). The load
average before and after each repeat is printed: on a shared machine the steps/s are only as good as
the cores were free.
"""

from __future__ import annotations

import argparse
import os
import tempfile
from dataclasses import replace
from pathlib import Path

import numpy as np

from m2h_ros.core.sounds.library import SoundLibrary
from m2h_ros.core.world.episodes import EpisodeConfig
from m2h_ros.machine import availability_line
from m2h_ros.paths import REPO_DIR
from m2h_ros.training.ppo import TIMED_PARTS, PPOTrainer
from m2h_ros.training.ppo_config import KINDS, PPOConfig
from m2h_ros.training.ppo_cli import build_parser, config_from_args
from m2h_ros.training.rewards import QUALITY_REWARDS

SHIPPED_QUALITY_RECIPE = REPO_DIR / "params" / "recipes" / "policy_quality.args"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--kind", default="quality", choices=sorted(KINDS))
    parser.add_argument("--preset", default="compact")
    parser.add_argument("--updates", type=int, default=4, help="per repeat, the first one a warm-up")
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--n-envs", type=int, default=16)
    parser.add_argument("--n-steps", type=int, default=20)
    parser.add_argument("--threads", type=int, default=2)
    parser.add_argument("--no-camera", action="store_true")
    parser.add_argument("--refiner-epochs", type=int, default=PPOConfig.refiner_epochs)
    parser.add_argument("--frozen-refiner", action="store_true", help="no f^R update (train_policy.py's flag)")
    parser.add_argument("--quality-reward", default=PPOConfig.quality_reward, choices=QUALITY_REWARDS)
    parser.add_argument("--location-coef", type=float, default=PPOConfig.location_coef)
    parser.add_argument("--shipped-quality", action="store_true",
                        help=f"the shipped pi^Q's recipe ({SHIPPED_QUALITY_RECIPE.relative_to(REPO_DIR)}: 32 slots, "
                             "f^R frozen, SI-SDR reward, location term 1); of the options above only --updates, "
                             "--repeats, --n-steps and --threads then apply")
    args = parser.parse_args()
    library = SoundLibrary.load()
    episodes = EpisodeConfig(task=KINDS[args.kind].task, scene_split="test", sound_split="heard", count=200)
    if args.shipped_quality:
        recipe = config_from_args(build_parser().parse_args([f"@{SHIPPED_QUALITY_RECIPE}"]))
        episodes = replace(episodes, task=recipe.episodes.task)
        config = replace(recipe, episodes=episodes, n_steps=args.n_steps, updates=args.updates, threads=args.threads,
                         checkpoint_every=args.updates + 1)
    else:
        config = PPOConfig(kind=args.kind, preset=args.preset, episodes=episodes,
                           env=KINDS[args.kind].env(camera=not args.no_camera), n_envs=args.n_envs, n_steps=args.n_steps,
                           updates=args.updates, threads=args.threads, refiner_epochs=args.refiner_epochs,
                           train_refiner=False if args.frozen_refiner else None,
                           quality_reward=args.quality_reward, location_coef=args.location_coef,
                           checkpoint_every=args.updates + 1)
    print(f"PPO {config.kind}, {config.preset} policy, {config.n_envs} slots x {config.n_steps} steps per update, "
          f"camera {'on' if config.env.camera else 'off'}, f^R trained: {config.refiner_trained} "
          f"({config.refiner_epochs} passes), {config.quality_reward} reward, location term {config.location_coef}, "
          f"{config.threads} torch threads, {os.cpu_count()} CPUs")
    print(availability_line())
    for repeat in range(args.repeats):
        before = os.getloadavg()[0]
        with tempfile.TemporaryDirectory() as out:
            trainer = PPOTrainer(config, library, out_dir=Path(out), progress=False)
            trainer.env.prepare(progress=False)
            try:
                history = trainer.run(stop_after=args.updates).history[1:]
            finally:
                trainer.env.close()
            runner = trainer.runner
            reused = runner.cache_hits / max(runner.cache_hits + runner.cache_misses, 1)
        sps = [h["sps"] for h in history]
        cpu = np.median([h["cpu_ms_per_step"] for h in history])
        shares = {p: np.median([h[f"{p}_share"] for h in history]) for p in TIMED_PARTS}
        print(f"repeat {repeat + 1}: {np.median(sps):.0f} env steps/s (updates {', '.join(f'{s:.0f}' for s in sps)}), "
              f"{cpu:.1f} CPU ms per env step (all threads); "
              + ", ".join(f"{p} {100 * v:.0f}%" for p, v in shares.items())
              + f"; f^B/f^M reused for {100 * reused:.0f}% of the separated observations"
              + f"; load average {before:.1f} -> {os.getloadavg()[0]:.1f}")


if __name__ == "__main__":
    main()
