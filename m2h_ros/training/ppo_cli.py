"""The command line of PPO training (``scripts/train_policy.py``; under ``torchrun`` for DD-PPO): flags ->
:class:`~m2h_ros.training.ppo_config.PPOConfig` -> :func:`~m2h_ros.training.ppo.train`.

    python scripts/train_policy.py --kind quality|navigation|approach|novelty|av_navigator [--updates N] [--out DIR]
    python scripts/train_policy.py @params/recipes/policy_quality.args --seed 1 --out runs/mine   # a shipped recipe
"""

from __future__ import annotations

import argparse
import os
import shlex
import sys
from pathlib import Path

# Spinning OpenMP workers collapse torch's speed on a shared machine (see pretrain_separator).
os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")

from m2h_ros.core.sounds.library import SoundLibrary  # noqa: E402
from m2h_ros.core.world.acoustics import BACKENDS, BACKEND_HELP, AcousticsConfig  # noqa: E402
from m2h_ros.core.world.episodes import TASKS, EpisodeConfig  # noqa: E402
from m2h_ros.core.world.hrtf import HEAD_HELP, KEMAR  # noqa: E402
from m2h_ros.errors import reports_errors  # noqa: E402
from m2h_ros.models.device import DEVICES  # noqa: E402
from m2h_ros.models.policy import PRESET_NAMES  # noqa: E402
from m2h_ros.training.distributed import close_distributed  # noqa: E402
from m2h_ros.training.ppo import train  # noqa: E402
from m2h_ros.training.ppo_config import KINDS, TRAIN_FAR_STEPS, TRAINING_SCENE_SPLITS, PPOConfig  # noqa: E402
from m2h_ros.training.rewards import QUALITY_REWARDS  # noqa: E402


class _RecipeArgumentParser(argparse.ArgumentParser):
    """Reads ``@FILE`` arguments (the shipped recipes in ``params/recipes/``) as shell words, '#' a comment."""

    def convert_arg_line_to_args(self, arg_line: str) -> list[str]:
        return shlex.split(arg_line, comments=True)


def build_parser() -> argparse.ArgumentParser:
    parser = _RecipeArgumentParser(
        description="Train a learned controller with PPO (DD-PPO under torchrun). @FILE reads arguments from FILE "
                    "(e.g. @params/recipes/policy_quality.args, the shipped pi^Q's); later ones override it.",
        fromfile_prefix_chars="@")
    parser.add_argument("--kind", required=True, choices=sorted(KINDS))
    parser.add_argument("--preset", default="compact", choices=PRESET_NAMES)
    parser.add_argument("--updates", type=int, default=PPOConfig.updates)
    parser.add_argument("--n-envs", type=int, default=PPOConfig.n_envs)
    parser.add_argument("--n-steps", type=int, default=PPOConfig.n_steps)
    parser.add_argument("--episodes", type=int, default=2000, help="training episodes (train scenes, heard sounds)")
    parser.add_argument("--task", choices=TASKS, help="default: the kind's")
    parser.add_argument("--scene-split", default="train", choices=TRAINING_SCENE_SPLITS,
                        help="training scenes: train (12), train24 (24) or train48 (48); each holds the one before")
    parser.add_argument("--world", default="", metavar="SPEC",
                        help="train (fine-tune, with --init-policy) in an imported world instead: map:PATH/map.yaml "
                             "(a nav2 map) or mesh:PATH (glb, gltf, obj, ply)")
    parser.add_argument("--separator", default="", help="separator checkpoint (default: the shipped one)")
    parser.add_argument("--no-camera", action="store_true", help="no RGB encoder (audio-only policy)")
    parser.add_argument("--head", default=KEMAR, help=HEAD_HELP)
    parser.add_argument("--acoustics-backend", default="project", choices=BACKENDS, help=BACKEND_HELP)
    parser.add_argument("--refiner-epochs", type=int, default=PPOConfig.refiner_epochs,
                        help="passes of f^R's L1 per update (quality)")
    parser.add_argument("--frozen-refiner", action=argparse.BooleanOptionalAction, default=False,
                        help="keep the separator's f^R as it is (quality trains it by default; --no-frozen-refiner "
                             "after a recipe that freezes it trains it)")
    parser.add_argument("--quality-reward", default=PPOConfig.quality_reward, choices=QUALITY_REWARDS,
                        help="quality: the measure whose improvement is the reward (nmse: the original's)")
    parser.add_argument("--final-weight", type=float, default=PPOConfig.final_weight,
                        help="quality: weight of the measure at the last step (0: the reward is the improvement alone)")
    parser.add_argument("--navigation-coef", type=float, default=PPOConfig.navigation_coef,
                        help="quality: add this weight x the env's navigation reward (0.25 per metre gained toward "
                             "the target, -0.01 a step; 0: quality alone)")
    parser.add_argument("--lr", type=float, default=PPOConfig.lr, help="Adam learning rate (the seed's 1e-4)")
    parser.add_argument("--teacher-coef", type=float, default=PPOConfig.teacher_coef,
                        help="kickstart with the approach teacher (m2h_ros/training/teacher.py): weight of its "
                             "cross-entropy, decaying with lr (0: plain PPO)")
    parser.add_argument("--location-coef", type=float, default=PPOConfig.location_coef,
                        help="weight of the auxiliary loss of predicting where the target is from the GRU's "
                             "output (m2h_ros/training/location.py; 0: none)")
    parser.add_argument("--init-policy", default="",
                        help="start from this policy checkpoint's weights (e.g. pi^Q from the shipped pi^N: "
                             "everything but the Stop logit), not random ones")
    parser.add_argument("--frozen-policy", action="store_true",
                        help="an f^R-only stage: no PPO update, the policy (--init-policy) acts as loaded")
    parser.add_argument("--teacher-slots", type=int, default=PPOConfig.teacher_slots,
                        help="with --frozen-policy: this many slots act with the approach teacher instead (f^R also "
                             "learns from walks that reach the target and hold still there)")
    parser.add_argument("--entropy-coef", type=float, default=None,
                        help="entropy coefficient (default: the kind's, the seed's 0.01 for quality, 0.2 otherwise)")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--threads", type=int, default=PPOConfig.threads)
    parser.add_argument("--checkpoint-every", type=int, default=PPOConfig.checkpoint_every)
    parser.add_argument("--device", default="auto", choices=DEVICES)
    parser.add_argument("--out", type=Path, help="run directory (default runs/policy_<kind>)")
    parser.add_argument("--fresh", action="store_true", help="start over even if --out holds a resume state")
    return parser


def config_from_args(args: argparse.Namespace) -> PPOConfig:
    """The run :func:`main` makes of ``build_parser()``'s arguments."""
    task = args.task or KINDS[args.kind].task
    episodes = EpisodeConfig(task=task, scene_split=args.world or args.scene_split, sound_split="heard", count=args.episodes, seed=args.seed,
                             max_steps=TRAIN_FAR_STEPS if task == "far_target" else None)
    return PPOConfig(kind=args.kind, preset=args.preset, episodes=episodes,
                     env=KINDS[args.kind].env(camera=not args.no_camera,
                                              acoustics=AcousticsConfig(head=args.head,
                                                                        backend=args.acoustics_backend)),
                     separator=args.separator, n_envs=args.n_envs,
                     n_steps=args.n_steps, updates=args.updates, refiner_epochs=args.refiner_epochs,
                     train_refiner=False if args.frozen_refiner else None, quality_reward=args.quality_reward,
                     final_weight=args.final_weight, navigation_coef=args.navigation_coef, lr=args.lr,
                     teacher_coef=args.teacher_coef, init_policy=args.init_policy,
                     location_coef=args.location_coef, frozen_policy=args.frozen_policy,
                     teacher_slots=args.teacher_slots,
                     entropy_coef=args.entropy_coef, seed=args.seed,
                     threads=args.threads, checkpoint_every=args.checkpoint_every, device=args.device)


@reports_errors("train_policy")
def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    config = config_from_args(args)
    command = shlex.join(["python", "scripts/train_policy.py", *(sys.argv[1:] if argv is None else argv)])
    result = train(config, SoundLibrary.load(), out_dir=args.out or Path("runs") / f"policy_{args.kind}",
                   command=command, fresh=args.fresh)
    close_distributed()
    last = result.history[-1] if result.history else {}
    print(f"[train_policy] {args.kind}: {last.get('update', 0)} updates, {last.get('env_steps', 0)} env steps; "
          f"policy {result.checkpoint}, log {result.out_dir / 'log.csv'}, curve {result.out_dir / 'curve.png'}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
