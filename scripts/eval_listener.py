#!/usr/bin/env python3
"""What a listener gets: separator/audio against the raw microphone (floor), the earlier refined output
and an ideal-mask oracle, by SI-SDR and STOI against the target's early image and as heard.

    python scripts/eval_listener.py --task near_target --count 500 --out docs/results/live_output/near_target
    python scripts/eval_listener.py --controller move2hear --count 500 --out docs/results/listener/moved
    python scripts/eval_listener.py --controller move2hear --task far_target --count 500 \
        --out docs/results/listener/moved_far_target
    python scripts/eval_listener.py --head free_field:0.2 --listener runs/heads/listener_free_field.pt \
        --paired-with runs/heads/shipped_free_field --out runs/heads/free_field

Step 0 (Stand In-Place) of the first --count test episodes of each sound split, or with --controller
the last step of the episodes it plays, where every estimate is also paired against Stand In-Place's
microphone at that step (its own run of the same episodes). Near-target episodes end together (step
20) and play 16 at a time; far-target ones end when the controller stops and play one at a time.
--head hears the episodes through another head; --paired-with adds the listener's paired difference
from another listener's run of the same episodes (its --out folder, whose results.json keeps the
per-episode scores).
Definitions in ``m2h_ros/training/listener_eval.py``. Writes results.md and results.json into --out.
"""

from __future__ import annotations

import argparse
import json
import shlex
import sys
import time
from datetime import date
from pathlib import Path

import numpy as np

from m2h_ros.agents.registry import controller_class, make_controller
from m2h_ros.core.sounds.library import SoundLibrary
from m2h_ros.core.results import mean_sem
from m2h_ros.core.world.acoustics import AcousticsConfig
from m2h_ros.core.world.env import EnvConfig
from m2h_ros.core.world.hrtf import HEAD_HELP, KEMAR
from m2h_ros.core.world.episodes import SOUND_SPLITS, TASKS, EpisodeConfig, episodes_for
from m2h_ros.errors import ConfigError, reports_errors
from m2h_ros.models.checkpoint import DEFAULT_SEPARATOR_CHECKPOINT, load_separator
from m2h_ros.models.listener import DEFAULT_LISTENER_CHECKPOINT, load_listener
from m2h_ros.paths import file_label, repo_relative
from m2h_ros.training.listener_eval import ESTIMATES, REFERENCES, STAND_IN_PLACE, evaluate_listener, summarize

LABELS = {"microphone": "microphone (floor)", "listener": "output: listener", "masked_mixture": "masked mixture",
          "refined": "refined", "oracle": "ideal mask (oracle)", STAND_IN_PLACE: "microphone, Stand In-Place"}
REFERENCE_LABELS = {"early": "early image (direct + 50 ms)", "as_heard": "as heard (whole RIR)"}


def format_table(results: dict[str, dict]) -> str:
    moved = any(STAND_IN_PLACE in summary for summary in results.values())
    baselines = ["microphone", *([STAND_IN_PLACE] if moved else [])]
    lines = []
    for reference in REFERENCES:
        header = " | ".join(f"vs {LABELS[b].split(' (')[0]} (paired)" for b in baselines)
        lines += [f"\nAgainst the target's {REFERENCE_LABELS[reference]}, ear mean:\n",
                  f"| sounds | estimate | SI-SDR (dB) | {header} | STOI (speech) | n (speech) |",
                  "|---|---|---|" + "---|" * len(baselines) + "---|---|"]
        for split, summary in results.items():
            for estimate in (e for e in (*ESTIMATES, STAND_IN_PLACE) if e in summary):
                s, sdr, st = summary[estimate], f"si_sdr_{reference}", f"stoi_{reference}"
                paired = " | ".join("" if estimate == b else f"{s[f'{sdr}_minus_{b}']:+.2f} ± {s[f'{sdr}_minus_{b}_sem']:.2f}"
                                    for b in baselines)
                stoi = f"{s[st]:.3f} ± {s[st + '_sem']:.3f} | {s[sdr + '_n']} ({s[st + '_n']})" if st in s else \
                    f"| {s[sdr + '_n']}"
                lines.append(f"| {split} | {LABELS[estimate]} | {s[sdr]:.2f} ± {s[sdr + '_sem']:.2f} | {paired} | {stoi} |")
    return "\n".join(lines)


PAIRED_METRICS = ("si_sdr_early", "stoi_early")


def paired_table(scores: dict[str, dict], other: dict, other_path: Path) -> str:
    """This run's listener minus the listener of ``other`` (another run's results.json), episode by episode."""
    lines = [f"\nThe listener minus {other['listener']} ({other_path}), paired on the same episodes:\n",
             "| sounds | SI-SDR early (dB) | better on | STOI early (speech) |", "|---|---|---|---|"]
    for split, mine in scores.items():
        theirs = other.get("per_episode", {}).get(split)
        if theirs is None:
            raise ConfigError(f"--paired-with {other_path}: no per-episode scores for the {split} split")
        cells = []
        for metric in PAIRED_METRICS:
            diff = mine["listener"][metric] - np.array(theirs[metric], dtype=float)
            diff = diff[np.isfinite(diff)]
            mean, sem = mean_sem(diff)
            cells.append(f"{mean:+.3f} ± {sem:.3f}")
            if metric == "si_sdr_early":
                cells.append(f"{int((diff > 0).sum())} of {len(diff)}")
        lines.append(f"| {split} | {' | '.join(cells)} |")
    return "\n".join(lines)


@reports_errors("eval_listener")
def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--checkpoint", type=Path, default=DEFAULT_SEPARATOR_CHECKPOINT)
    parser.add_argument("--listener", type=Path, default=DEFAULT_LISTENER_CHECKPOINT,
                        help="listener checkpoint to score (default: the shipped one)")
    parser.add_argument("--count", type=int, default=500, help="episodes per sound split")
    parser.add_argument("--task", choices=TASKS, default="near_target")
    parser.add_argument("--sound-split", choices=SOUND_SPLITS, action="append", help="default: both")
    parser.add_argument("--controller", metavar="NAME",
                        help="score the last step of the episodes this controller plays, paired against Stand "
                             "In-Place's microphone there; default: step 0")
    parser.add_argument("--head", default=KEMAR, help=HEAD_HELP)
    parser.add_argument("--paired-with", type=Path, metavar="RUN",
                        help="another listener's run (its --out folder) on the same episodes, head and step: add "
                             "the paired difference of the listeners")
    parser.add_argument("--out", type=Path, required=True, help="folder for results.md and results.json")
    args = parser.parse_args(argv)
    setting = {"task": args.task, "count_per_split": args.count, "head": args.head, "controller": args.controller}
    other = None
    if args.paired_with:
        try:
            other = json.loads((args.paired_with / "results.json").read_text())
        except (OSError, ValueError) as error:
            raise ConfigError(f"--paired-with {args.paired_with}: cannot read it ({error})") from error
        for key, mine in setting.items():
            if other.get(key, KEMAR if key == "head" else None) != mine:
                raise ConfigError(f"--paired-with {args.paired_with}: its {key} is {other.get(key)!r}, this run's "
                                  f"{mine!r}: pair runs of the same episodes")
    acoustics = AcousticsConfig(head=args.head)
    loaded = load_separator(args.checkpoint)
    listener = load_listener(args.listener)
    library = SoundLibrary.load()
    results, per_split, started = {}, {}, time.perf_counter()
    for split in args.sound_split or SOUND_SPLITS:
        episodes = episodes_for(EpisodeConfig(task=args.task, scene_split="test", sound_split=split),
                                library)[: args.count]
        scores = {}
        for name in ([args.controller, "stand_in_place"] if args.controller else [None]):
            # A batch's slots must end together: far-target episodes end where the controller stops
            # (Stand In-Place never does: all at step 100).
            one_at_a_time = args.task == "far_target" and name not in (None, "stand_in_place")
            slots = 1 if one_at_a_time else min(16, len(episodes))
            controller = None if name is None else make_controller(name, slots)
            played = evaluate_listener(loaded, episodes, library, n_envs=slots, controller=controller,
                                       env_config=EnvConfig(camera=name is not None and controller_class(name).uses_camera,
                                                            acoustics=acoustics),
                                       listener=listener)
            scores = scores or played
            if name == "stand_in_place" and args.controller:
                scores[STAND_IN_PLACE] = played["microphone"]
        results[split], per_split[split] = summarize(scores), scores
    given = sys.argv[1:] if argv is None else argv
    command = shlex.join(["python", "scripts/eval_listener.py", *given])
    table = format_table(results) + ("" if other is None else "\n" + paired_table(per_split, other, args.paired_with))
    step = f"last step after {args.controller}" if args.controller else "step 0"
    wall = round(time.perf_counter() - started, 1)
    print(table)
    args.out.mkdir(parents=True, exist_ok=True)
    (args.out / "results.md").write_text(
        f"# What a listener gets: {args.task}, {step}, {args.count} test episodes per sound split\n\n"
        f"`{command}` ({date.today().isoformat()}, {wall} s)\n\nSeparator: {file_label(args.checkpoint)}; "
        f"listener: {file_label(args.listener)}; head: {args.head}\n"
        f"{table}\n")
    (args.out / "results.json").write_text(json.dumps(
        {"command": command, "checkpoint": repo_relative(args.checkpoint), "listener": repo_relative(args.listener),
         "scene_split": "test", "step": "last" if args.controller else 0, **setting, "wall_seconds": wall,
         "results": results,
         "per_episode": {split: {metric: [None if not np.isfinite(x) else float(x) for x in scores["listener"][metric]]
                                 for metric in PAIRED_METRICS} for split, scores in per_split.items()}},
        indent=1) + "\n")
    print(f"wrote {repo_relative(args.out)}/results.md, results.json")
    return 0


if __name__ == "__main__":
    sys.exit(main())
