#!/usr/bin/env python3
"""Diagnostic: how far-target walkers approach the target in the scenes they trained in and in unseen ones.

    python scripts/experiments/scene_generalisation.py [--controllers move2hear,gan_et_al@CKPT,...] [--count 100]
        [--sound-split heard] [--seed 7] [--step 80] [--threads 2] [--out DIR]

Plays each controller (``SPEC`` or ``SPEC@CHECKPOINT``, as ``scripts/evaluate.py --policy-checkpoint``) on far-target
episodes of the train scenes drawn with ``--seed`` (the policies trained on seed 0's: those episodes, start, target and
heading alike, are counted and reported) and on the first ``--count`` validation episodes, and reports per scene split
the mean geodesic distance gained by step ``--step`` (T^N, the composite's switch: what its navigation phase did) and
the shares of episodes ending on, or ever on, the target's node. The learned policies and Gan et al.'s locator all
trained on the train scenes; a walker that gains much less in unseen scenes has learned those scenes, not hearing.
"""

import argparse
import os
import shlex
import sys
import time
from pathlib import Path

os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")

import numpy as np  # noqa: E402
import torch  # noqa: E402

from m2h_ros.agents.registry import controller_class, make_controller  # noqa: E402
from m2h_ros.agents.rollout import evaluate_controller  # noqa: E402
from m2h_ros.core.sounds.library import SoundLibrary  # noqa: E402
from m2h_ros.core.world.env import EnvConfig  # noqa: E402
from m2h_ros.core.world.episodes import SOUND_SPLITS, Episode, EpisodeConfig, episodes_for  # noqa: E402
from m2h_ros.errors import ConfigError, reports_errors  # noqa: E402
from m2h_ros.experiments.reach import geodesic_trace, walk_group  # noqa: E402
from m2h_ros.machine import load_averages  # noqa: E402
from m2h_ros.models.checkpoint import DEFAULT_SEPARATOR_CHECKPOINT, load_separator  # noqa: E402
from m2h_ros.models.runner import SeparatorRunner  # noqa: E402
from m2h_ros.paths import RUNS_DIR  # noqa: E402
from m2h_ros.training.ppo_config import TRAIN_FAR_STEPS  # noqa: E402

TRAINING_SEED = 0  # the shipped far-target recipes' episode seed (params/recipes/*.args)


def scene_episodes(scene_split: str, sound_split: str, *, count: int, seed: int, library) -> list[Episode]:
    """Far-target episodes: the train scenes' drawn with ``seed``, else the split's own first ``count``."""
    if scene_split == "train":
        return episodes_for(EpisodeConfig(task="far_target", scene_split="train", sound_split=sound_split, count=count,
                                          seed=seed), library)
    return episodes_for(EpisodeConfig(task="far_target", scene_split=scene_split, sound_split=sound_split),
                        library)[:count]


def seen_in_training(episodes: list[Episode], sound_split: str, library) -> int:
    """How many of ``episodes`` (scene, start, target, heading) a shipped recipe's 10,000 training episodes hold."""
    training = episodes_for(EpisodeConfig(task="far_target", scene_split="train", sound_split=sound_split, count=10000,
                                          seed=TRAINING_SEED, max_steps=TRAIN_FAR_STEPS), library)
    key = lambda e: (e.scene_id, e.start_node, e.target_node, e.start_heading)  # noqa: E731
    known = {key(e) for e in training}
    return sum(key(e) in known for e in episodes)


@reports_errors("scene_generalisation")
def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--controllers", default="move2hear,gan_et_al",
                        help="comma-separated SPEC or SPEC@CHECKPOINT (a learned controller's policy file or folder)")
    parser.add_argument("--sound-split", default="heard", choices=SOUND_SPLITS)
    parser.add_argument("--count", type=int, default=100, help="episodes per scene split")
    parser.add_argument("--seed", type=int, default=7, help="seed of the train scenes' episodes (training used 0)")
    parser.add_argument("--step", type=int, default=80, help="distance gained by this step (T^N)")
    parser.add_argument("--slots", type=int, default=8)
    parser.add_argument("--threads", type=int, default=2)
    parser.add_argument("--out", type=Path, default=RUNS_DIR / "scene_generalisation",
                        help="output folder (default: %(default)s)")
    args = parser.parse_args(argv)
    command = shlex.join(["python", "scripts/experiments/scene_generalisation.py", *(sys.argv[1:] if argv is None else argv)])
    started = time.perf_counter()
    specs = [item.partition("@") for item in args.controllers.split(",")]
    for name, _, _ in specs:
        controller_class(name)  # an unknown spec fails here, before minutes of episodes
    if args.seed == TRAINING_SEED or min(args.count, args.slots, args.threads, args.step) < 1:
        raise ConfigError(f"--seed must differ from the training's {TRAINING_SEED}; --count, --slots, --threads, "
                          f"--step >= 1")
    torch.set_num_threads(args.threads)
    library, loaded = SoundLibrary.load(), load_separator(DEFAULT_SEPARATOR_CHECKPOINT)
    rows = []
    for scene_split in ("train", "val"):
        episodes = scene_episodes(scene_split, args.sound_split, count=args.count, seed=args.seed, library=library)
        seen = seen_in_training(episodes, args.sound_split, library) if scene_split == "train" else 0
        by_id = {e.episode_id: e for e in episodes}
        slots = min(args.slots, len(episodes))
        for name, _, checkpoint in specs:
            controller = make_controller(name, slots, checkpoint=checkpoint)
            results = evaluate_controller(controller, SeparatorRunner(loaded, slots), episodes, library,
                                          env_config=EnvConfig(camera=controller.uses_camera),
                                          threads=args.threads, progress=False)
            traces = [geodesic_trace(by_id[r.episode_id], r.actions) for r in results]
            groups = [walk_group(t) for t in traces]
            rows.append((scene_split, f"{name}{'@' + checkpoint if checkpoint else ''}", len(traces), seen,
                         float(np.mean([t[0] for t in traces])),
                         float(np.mean([t[0] - t[min(args.step, len(t) - 1)] for t in traces])),
                         groups.count("ends on target") / len(groups),
                         1 - groups.count("never on it") / len(groups)))
    lines = [f"| scenes | controller | episodes | of them in training | start (m) | gained by step {args.step} (m) "
             "| ends on target | ever on target |", "|---|---|---|---|---|---|---|---|"]
    lines += [f"| {s} | {c} | {n} | {seen} | {start:.2f} | {gain:.2f} | {ends:.3f} | {ever:.3f} |"
              for s, c, n, seen, start, gain, ends, ever in rows]
    table = "\n".join(lines)
    print(table)
    args.out.mkdir(parents=True, exist_ok=True)
    path = args.out / "results.md"
    path.write_text(f"# Far-target walks in the training scenes and in unseen ones\n\nCommand: `{command}`\n\n"
                    f"Far-target, {args.sound_split} sounds; train scenes: episodes of seed {args.seed} (the recipes "
                    f"trained on seed {TRAINING_SEED}'s; the column says how many of these are among those); val: the "
                    f"split's first {args.count}. Separator: the shipped one. {time.perf_counter() - started:.0f} s, "
                    f"load average {load_averages()}.\n\n{table}\n")
    print(f"markdown: {path}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
