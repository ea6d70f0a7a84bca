#!/usr/bin/env python3
"""Evaluate controllers in-process (no ROS) on the test episodes of a task and sound split(s).

    python scripts/evaluate.py [--controllers stand_in_place,random,...] [--task near_target]
        [--sound-split heard,unheard] [--scene-split test] [--count 1000] [--first 0] [--slots 16] [--seed 0]
        [--mic-noise 0] [--checkpoint m2h_ros/models/default/separator_compact.pt]
        [--out out/evaluate] [--threads 2] [--reference stand_in_place] [--list]

Each controller plays every selected episode once on a batched environment (``--slots`` episodes at
a time) with the separator (f^B, f^M, f^R) batched over the same slots, scored at every step by the
same functions as the evaluator node. Prints the paper-style table (final-step SI-SDR in the
ground-truth-phase and mixture-phase variants, STFT distance: mean ± 95% CI; SR and SPL for
far-target), each controller's final-step SI-SDR minus ``--reference``'s on the same episodes
(paired: mean ± 95% CI), and writes results.md / .csv / .json and si_sdr_vs_step.png into ``--out``.
``--scene-split val`` plays the validation episodes instead: choose models and settings there, report on test
(``train`` / ``train24`` / ``train48``: the training scenes, to compare a policy where it trained with where it did not).
"""

from __future__ import annotations

import argparse
import os
import shlex
import sys
import time
from collections.abc import Sequence
from pathlib import Path

os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")  # before torch: idle OpenMP threads must not spin

import torch  # noqa: E402

from m2h_ros.agents.registry import (CONTROLLER_NAMES, GREEDY, LEARNED, LEARNED_VARIANTS, PLUGINS,  # noqa: E402
                                     SUPERVISED, TRAINING_FREE, controller_class, make_controller)
from m2h_ros.agents.rollout import evaluate_controller  # noqa: E402
from m2h_ros.core.results import (EpisodeResult, markdown_table, paired_differences, paired_table,  # noqa: E402
                                  summarize, write_results)
from m2h_ros.core.sounds.library import SoundLibrary  # noqa: E402
from m2h_ros.core.world import acoustics  # noqa: E402
from m2h_ros.core.world.acoustics import BACKENDS, BACKEND_HELP, AcousticsConfig  # noqa: E402
from m2h_ros.core.world.hrtf import HEAD_HELP, KEMAR  # noqa: E402
from m2h_ros.core.world.env import EnvConfig  # noqa: E402
from m2h_ros.core.world.episodes import SOUND_SPLITS, TASKS, Episode, EpisodeConfig, episodes_for  # noqa: E402
from m2h_ros.core.world.scene import SCENE_SPLITS  # noqa: E402
from m2h_ros.core.world.worlds import load_world, parse_world_spec  # noqa: E402
from m2h_ros.errors import ConfigError, reports_errors  # noqa: E402
from m2h_ros.machine import load_averages  # noqa: E402
from m2h_ros.models.checkpoint import DEFAULT_SEPARATOR_CHECKPOINT, LoadedSeparator, load_separator  # noqa: E402
from m2h_ros.models.runner import SeparatorRunner  # noqa: E402
from m2h_ros.paths import file_label, file_sha256, repo_relative  # noqa: E402


def names(text: str, *, allowed: Sequence[str], what: str) -> list[str]:
    """A comma-separated list, each item one of ``allowed`` (ConfigError naming the bad one)."""
    items = [item.strip() for item in text.split(",") if item.strip()]
    if not items:
        raise ConfigError(f"no {what} given")
    for item in items:
        if item not in allowed:
            raise ConfigError(f"unknown {what} {item!r}; available: {', '.join(allowed)}")
    return items


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--controllers", default=",".join((*TRAINING_FREE, *LEARNED, *SUPERVISED, *PLUGINS)),
                        help="comma-separated controller names (default: all; --list shows them); a learned "
                             "one with ':greedy' takes the most likely action instead of sampling")
    parser.add_argument("--task", choices=TASKS, default="near_target")
    parser.add_argument("--sound-split", default="unheard", help="heard, unheard or both comma-separated")
    parser.add_argument("--scene-split", default="test", choices=tuple(SCENE_SPLITS),
                        help="val: the validation scenes' episodes (for choosing models), test: the reported ones; "
                             "train / train24 / train48: the training scenes' (a diagnostic: a policy where it trained)")
    parser.add_argument("--world", default="", metavar="SPEC",
                        help="evaluate in an imported world instead of --scene-split's scenes: map:PATH/map.yaml "
                             "(a nav2 map) or mesh:PATH (glb, gltf, obj, ply)")
    parser.add_argument("--min-source-distance", type=float, default=8.0,
                        help="minimum geodesic metres between sources (8 as the original; a small world needs less)")
    parser.add_argument("--count", type=int, default=1000, help="episodes per sound split")
    parser.add_argument("--first", type=int, default=0, help="index of the first episode of the split")
    parser.add_argument("--slots", type=int, default=16, help="episodes played at once")
    parser.add_argument("--seed", type=int, default=0, help="seed of the stochastic controllers")
    parser.add_argument("--mic-noise", type=float, default=0.0, help="microphone noise std / mixture RMS")
    parser.add_argument("--head", default=KEMAR, help=HEAD_HELP)
    parser.add_argument("--acoustics-backend", default="project", choices=BACKENDS, help=BACKEND_HELP)
    parser.add_argument("--checkpoint", type=Path, default=DEFAULT_SEPARATOR_CHECKPOINT, help="separator")
    parser.add_argument("--policy-checkpoint", default="",
                        help="policy file (a directory for move2hear) for the learned controllers; "
                             "default: the shipped ones")
    parser.add_argument("--locator-checkpoint", default="",
                        help="sound locator of gan_et_al (default: the shipped one)")
    parser.add_argument("--out", type=Path, default=Path("out/evaluate"), help="output directory")
    parser.add_argument("--threads", type=int, default=2,
                        help="torch and rendering threads (2 suits 16 slots on 2 cores)")
    parser.add_argument("--reference", default="stand_in_place",
                        help="controller the others are compared with episode by episode (if evaluated)")
    parser.add_argument("--no-progress", action="store_true", help="no progress bars")
    parser.add_argument("--list", action="store_true", help="list the controllers and exit")
    return parser


def select_episodes(task: str, split: str, *, first: int, count: int, library: SoundLibrary,
                    scene_split: str = "test", min_source_distance: float = 8.0) -> list[Episode]:
    """Episodes first .. first + count - 1 of the standard episode file of a task x sound split
    (``scene_split`` test, val, a training split or an imported world's spec)."""
    episodes = episodes_for(EpisodeConfig(task=task, scene_split=scene_split, sound_split=split,
                                          min_source_distance=min_source_distance), library)
    if first < 0 or count < 1 or first + count > len(episodes):
        raise ConfigError(f"--first {first} --count {count} selects outside the {len(episodes)} "
                          f"{task} {split} {scene_split} episodes")
    return episodes[first:first + count]


def run(args: argparse.Namespace, controllers: Sequence[str], episodes: Sequence[Episode], *,
        loaded: LoadedSeparator, library: SoundLibrary, env_config: EnvConfig
        ) -> tuple[list[EpisodeResult], dict[str, list[Path]]]:
    """Every controller on every episode; results grouped by controller, episodes in list order; and
    the model files each controller ran."""
    results: list[EpisodeResult] = []
    model_files: dict[str, list[Path]] = {}
    slots = min(args.slots, len(episodes))
    for name in controllers:
        checkpoint = ("" if name in TRAINING_FREE else args.locator_checkpoint if name in SUPERVISED
                      else args.policy_checkpoint)
        controller = make_controller(name, slots, seed=args.seed, checkpoint=checkpoint)
        runner = SeparatorRunner(loaded, slots)
        results += evaluate_controller(controller, runner, episodes, library, env_config=env_config,
                                       threads=args.threads, progress=not args.no_progress)
        model_files[name] = controller.model_files()
    return results, model_files


def world_label(spec: str) -> str:
    """An imported world as a table names it: its kind, file (repo-relative) and fingerprint; "" for none."""
    if not spec:
        return ""
    world = load_world(spec)
    return f"{world.source} {repo_relative(parse_world_spec(spec)[1])} ({world.fingerprint()})"


def describe_models(model_files: dict[str, list[Path]]) -> dict[str, list[str]]:
    """Each controller's model files as "path (sha256 prefix)", for a table's setup line."""
    return {name: [file_label(path) for path in paths] for name, paths in model_files.items() if paths}


@reports_errors("evaluate")
def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    if args.list:
        for name in (*TRAINING_FREE, *LEARNED, *SUPERVISED):
            print(f"{name:<18} {controller_class(name).summary}")
        for name, target in PLUGINS.items():  # imported to show its summary: a broken plugin is named here
            print(f"{name:<18} {controller_class(name).summary} (plugin: {target})")
        for spec, variant in LEARNED_VARIANTS.items():
            print(f"{spec:<18} {variant.summary}")
        print(f"(a learned controller as <name>{GREEDY} takes the most likely action instead of sampling)")
        return 0
    command = shlex.join(["python", "scripts/evaluate.py", *(sys.argv[1:] if argv is None else argv)])
    started = time.perf_counter()
    controllers = names(args.controllers, allowed=CONTROLLER_NAMES, what="controller")
    splits = names(args.sound_split, allowed=SOUND_SPLITS, what="sound split")
    for option in ("slots", "threads"):
        if getattr(args, option) < 1:
            raise ConfigError(f"--{option.replace('_', '-')} must be >= 1")
    loaded = load_separator(args.checkpoint)
    torch.set_num_threads(args.threads)
    library = SoundLibrary.load()
    scene_split = args.world or args.scene_split
    episodes = [e for split in splits for e in select_episodes(args.task, split, first=args.first, count=args.count,
                                                                 library=library, scene_split=scene_split,
                                                                 min_source_distance=args.min_source_distance)]
    env_config = EnvConfig(camera=any(controller_class(n).uses_camera for n in controllers),
                           mic_noise=args.mic_noise,
                           acoustics=AcousticsConfig(head=args.head, backend=args.acoustics_backend))
    results, model_files = run(args, controllers, episodes, loaded=loaded, library=library, env_config=env_config)
    meta = {"command": command, "checkpoint": repo_relative(args.checkpoint),
            "policy_checkpoint": repo_relative(args.policy_checkpoint) if args.policy_checkpoint else "shipped",
            "task": args.task, "scene_split": args.scene_split if not args.world else "",
            "world": world_label(args.world),
            "sound_splits": splits, "first": args.first, "count_per_split": args.count,
            "head": args.head, "controller_seed": args.seed, "mic_noise": args.mic_noise, "slots": args.slots,
            "threads": args.threads, "wall_seconds": round(time.perf_counter() - started, 1),
            "load_average": load_averages()}
    reference = args.reference if args.reference in controllers else None
    meta["separator_sha256"] = file_sha256(loaded.path)
    meta["acoustics"] = f"v{acoustics.VERSION} {env_config.acoustics.digest()}"
    meta["models"] = describe_models(model_files)
    setup = (f"separator `{Path(loaded.path).name}` (sha256 {meta['separator_sha256']}), "
             f"acoustics {meta['acoustics']}"
             + "".join(f"; {name}: {', '.join(files)}" for name, files in meta["models"].items()))
    where = world_label(args.world) or args.scene_split
    paths = write_results(results, args.out, title=f"{args.task} {where} episodes, {' + '.join(splits)} sounds",
                          meta=meta, command=command, setup=setup, reference=reference)
    print(markdown_table(summarize(results)))
    if reference:
        print(f"final-step SI-SDR (GT phase) minus {reference}'s, same episodes:")
        print(paired_table(paired_differences(results, reference=reference)))
    print(f"{len(results)} episodes in {meta['wall_seconds']} s (load average {meta['load_average']})")
    for kind, path in paths.items():
        print(f"{kind}: {path}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
