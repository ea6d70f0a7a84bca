#!/usr/bin/env python3
"""Train the listener output (m2h_ros/models/listener.py) from the shipped separator's f^B.

    python scripts/train_listener.py --data train@default@0 --data train@default@1 --only-cached --poses 8 \\
        --filter-taps 3 --steps 5000 --out listener.pt --work runs/listener

Each --data is SCENES@ACOUSTICS@SEED: the scenes (a split such as ``train``, or a world spec), the
acoustics (``default``, or ``fast``: 0.25 s RIRs without the late tail, the tests' setting, whose banks
cost a fraction to build) and the episode list's seed; near- and far-target episodes with heard sounds,
each heard at ``--poses`` poses (its start, then random moves). ``--only-cached`` keeps only episodes
whose RIRs are already in the banks (no bank building).
Rendered examples and the trainer's state live in --work: a run that is killed resumes from there.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import os
import shlex
import sys
import time
from collections import Counter
from dataclasses import replace
from pathlib import Path

os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")  # before torch loads: idle threads must not spin

import numpy as np  # noqa: E402
from tqdm import tqdm  # noqa: E402

from m2h_ros.core.sounds.library import TARGET_CATEGORIES, SoundLibrary  # noqa: E402
from m2h_ros.core.world.acoustics import AcousticsConfig  # noqa: E402
from m2h_ros.core.world.hrtf import HEAD_HELP, KEMAR  # noqa: E402
from m2h_ros.core.world.env import EnvConfig  # noqa: E402
from m2h_ros.core.world.episodes import TASKS, EpisodeConfig, episodes_for, scene_at  # noqa: E402
from m2h_ros.core.world.rir_bank import RirBank, bank_dir  # noqa: E402
from m2h_ros.errors import ConfigError, reports_errors  # noqa: E402
from m2h_ros.models.checkpoint import DEFAULT_SEPARATOR_CHECKPOINT, load_separator  # noqa: E402
from m2h_ros.models.listener import Listener, ListenerConfig, load_listener, save_listener  # noqa: E402
from m2h_ros.paths import file_label, repo_relative  # noqa: E402
from m2h_ros.sim_world import ACOUSTICS_PRESETS  # noqa: E402
from m2h_ros.training.listener_train import (  # noqa: E402
    ListenerExamples, ListenerTrainConfig, render_examples, train_listener)


def parse_data(spec: str) -> tuple[str, str, int]:
    parts = spec.split("@")
    if len(parts) != 3 or parts[1] not in ACOUSTICS_PRESETS or not parts[2].isdigit():
        raise ConfigError(f"--data {spec!r}: expected SCENES@ACOUSTICS@SEED with ACOUSTICS one of "
                          f"{', '.join(ACOUSTICS_PRESETS)}, e.g. train@fast@0")
    return parts[0], parts[1], int(parts[2])


def acoustics_of(name: str, head: str) -> AcousticsConfig:
    """An ACOUSTICS_PRESETS entry heard through ``head``."""
    return replace(ACOUSTICS_PRESETS[name], head=head)


def banked(episodes, env_config: EnvConfig) -> list:
    """The episodes whose sources' RIRs are all on disk already."""
    folders, kept = {}, []
    for episode in episodes:
        key = (episode.scene_split, episode.scene_preset, episode.scene_index)
        if key not in folders:
            folders[key] = bank_dir(scene_at(*key), env_config.acoustics)
        if all((folders[key] / f"src_{node:04d}.npy").exists() for node in episode.source_nodes):
            kept.append(episode)
    return kept


def build_common_sources(spec: str, library: SoundLibrary, per_scene: int, *, head: str = KEMAR,
                         lists: int = 4000) -> None:
    """Build the RIRs of the ``per_scene`` source nodes of each scene that its episodes use most (over
    near- and far-target lists of ``lists`` episodes, seed 0): a bank's cost is per source node, and
    episodes whose sources are all common ones come cheap. Nodes already on disk are kept."""
    scenes, acoustics, _ = parse_data(spec)
    config = acoustics_of(acoustics, head)
    uses: Counter = Counter()
    for task in TASKS:
        for episode in episodes_for(EpisodeConfig(task=task, scene_split=scenes, sound_split="heard", count=lists),
                                    library):
            uses.update((episode.scene_split, episode.scene_preset, episode.scene_index, node)
                        for node in episode.source_nodes)
    for key in sorted({use[:3] for use in uses}):
        common = sorted((node for *scene, node in uses if tuple(scene) == key),
                        key=lambda node: (uses[(*key, node)], node), reverse=True)[:per_scene]
        bank = RirBank(scene_at(*key), config)
        for node in tqdm(common, desc=f"RIRs of {key[0]} {key[2]}", leave=False):
            bank.rirs([node], [0], [0])  # computes and stores the node's rows when absent


def examples_for(spec: str, library: SoundLibrary, work: Path, *, only_cached: bool, poses: int,
                 approach: float, head: str = KEMAR) -> ListenerExamples:
    scenes, acoustics, seed = parse_data(spec)
    key = hashlib.sha256(json.dumps([spec, only_cached] + ([poses] if poses > 1 else [])
                                    + ([approach] if approach else [])
                                    + ([head] if head != KEMAR else [])).encode()).hexdigest()[:12]
    path = work / f"examples_{key}.npz"
    if path.exists():
        return ListenerExamples.load(path)
    env_config = EnvConfig(camera=False, acoustics=acoustics_of(acoustics, head))
    parts = []
    for task in TASKS:
        episodes = episodes_for(EpisodeConfig(task=task, scene_split=scenes, sound_split="heard", seed=seed), library)
        if only_cached:
            episodes = banked(episodes, env_config)
        print(f"{spec} {task}: {len(episodes)} episodes", flush=True)
        if episodes:
            parts.append(render_examples(episodes, library, env_config=env_config, poses=poses, approach=approach,
                                         seed=seed))
    if not parts:
        raise ConfigError(f"--data {spec}: no episodes (with --only-cached: none has its RIRs on disk)")
    examples = ListenerExamples.concatenate(parts)
    examples.save(path)
    return examples


@reports_errors("train_listener")
def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data", action="append", required=True, help="SCENES@ACOUSTICS@SEED (repeatable)")
    parser.add_argument("--only-cached", action="store_true", help="skip episodes whose RIRs are not built")
    parser.add_argument("--poses", type=int, default=1, help="poses per episode: its start, then random moves")
    parser.add_argument("--approach", type=float, default=0.0, metavar="P",
                        help="each move after the start is a step toward the target with probability P, else "
                             "random: examples from where a robot that moves to hear better goes")
    parser.add_argument("--head", default=KEMAR, help=HEAD_HELP)
    parser.add_argument("--build-sources", type=int, default=0, metavar="K",
                        help="first build the RIRs of the K most used source nodes of each scene (with --only-cached)")
    parser.add_argument("--separator", type=Path, default=DEFAULT_SEPARATOR_CHECKPOINT, help="f^B to start from")
    parser.add_argument("--init", type=Path, help="a listener checkpoint to start from instead of f^B (fine-tuning)")
    parser.add_argument("--filter-taps", type=int, default=ListenerConfig.filter_taps,
                        help="frames the two-ear filter reads per bin (current + earlier)")
    parser.add_argument("--steps", type=int, default=ListenerTrainConfig.steps)
    parser.add_argument("--batch-size", type=int, default=ListenerTrainConfig.batch_size)
    parser.add_argument("--learning-rate", type=float, default=ListenerTrainConfig.learning_rate)
    parser.add_argument("--seed", type=int, default=ListenerTrainConfig.seed)
    parser.add_argument("--out", type=Path, required=True, help="listener checkpoint to write")
    parser.add_argument("--work", type=Path, required=True, help="folder for rendered examples and the resumable state")
    args = parser.parse_args(argv)
    for spec in args.data:
        parse_data(spec)
    config = ListenerTrainConfig(steps=args.steps, batch_size=args.batch_size, learning_rate=args.learning_rate,
                                 seed=args.seed)
    started = time.perf_counter()
    args.work.mkdir(parents=True, exist_ok=True)
    library = SoundLibrary.load()
    for spec in dict.fromkeys(f"{parse_data(spec)[0]}@{parse_data(spec)[1]}@0" for spec in args.data):
        if args.build_sources:
            build_common_sources(spec, library, args.build_sources, head=args.head)
    examples = ListenerExamples.concatenate([examples_for(spec, library, args.work, only_cached=args.only_cached,
                                                          poses=args.poses, approach=args.approach, head=args.head)
                                             for spec in args.data])
    rendered = round(time.perf_counter() - started, 1)
    print(f"{len(examples)} examples ({rendered} s)", flush=True)
    loaded = load_separator(args.separator)
    if args.init:
        start = load_listener(args.init)
        if start.classes != loaded.classes or start.listener.config.filter_taps != args.filter_taps:
            raise ConfigError(f"--init {args.init}: classes {list(start.classes)} and {start.listener.config.filter_taps} "
                              f"filter taps, expected {list(loaded.classes)} and --filter-taps {args.filter_taps}")
        listener = start.listener
    else:
        listener = Listener.from_separator(loaded.separator, filter_taps=args.filter_taps)
    class_map = np.array([loaded.class_index(name) for name in TARGET_CATEGORIES], np.int64)
    summary = train_listener(listener, examples, class_map=class_map, stft_config=loaded.stft, config=config,
                             state_path=args.work / "train_state.pt", log=lambda line: print(line, flush=True))
    given = sys.argv[1:] if argv is None else argv
    metadata = {"command": shlex.join(["python", "scripts/train_listener.py", *given]),
                "separator": file_label(args.separator), "examples": len(examples),
                "init": file_label(args.init) if args.init else None,
                "train_config": {k: getattr(config, k) for k in config.__dataclass_fields__},
                "history": summary["history"], "seconds_last_run": summary["seconds_this_run"],
                "seconds_rendering": rendered}
    save_listener(args.out, listener, classes=loaded.classes, stft_config=loaded.stft, metadata=metadata)
    print(f"wrote {repo_relative(args.out)}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
