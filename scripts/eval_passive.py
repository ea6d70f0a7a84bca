#!/usr/bin/env python3
"""Passive baseline on the held-out test episodes: separator (both phase variants) vs the mixture floor.

    python scripts/eval_passive.py [--checkpoint m2h_ros/models/default/separator_compact.pt] [--count 200]

Stand In-Place at step 0 of near-target test episodes (heard and unheard sounds; the first --count
episodes of the standard 1000-episode files), f^B + f^M + f^R with fresh memory. Prints a table and
writes JSON (default: <checkpoint stem>_passive.json next to the checkpoint).
"""

from __future__ import annotations

import argparse
import json
import shlex
import sys
import time
from pathlib import Path

from m2h_ros.core.sounds.library import SoundLibrary
from m2h_ros.core.world.episodes import SOUND_SPLITS, TASKS, EpisodeConfig, episodes_for
from m2h_ros.errors import M2HError
from m2h_ros.models.checkpoint import DEFAULT_SEPARATOR_CHECKPOINT, load_separator
from m2h_ros.training.passive_eval import REFERENCES, VARIANTS, evaluate_passive, summarize

LABELS = {"separator_gt_phase": "separator, GT phase (paper)", "separator_mixture_phase": "separator, mixture phase",
          "mixture_gt_phase": "mixture, GT phase", "mixture": "mixture (do nothing)"}


def format_table(results: dict[str, dict[str, dict[str, float]]]) -> str:
    lines = [f"{'sounds':<8} {'estimate':<30} {'scored vs':<25} {'SI-SDR dB':>16} {'STFT distance':>18} {'n':>5}"]
    for split, summary in results.items():
        for variant in VARIANTS:
            s = summary[variant]
            lines.append(f"{split:<8} {LABELS[variant]:<30} {REFERENCES[variant]:<25} {s['si_sdr']:>9.2f} ± {s['si_sdr_sem']:<4.2f} "
                         f"{s['stft_distance']:>10.1f} ± {s['stft_distance_sem']:<5.1f} {s['episodes']:>5}")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--checkpoint", type=Path, default=DEFAULT_SEPARATOR_CHECKPOINT)
    parser.add_argument("--count", type=int, default=200, help="episodes per sound split")
    parser.add_argument("--task", choices=TASKS, default="near_target")
    parser.add_argument("--sound-split", choices=SOUND_SPLITS, action="append", help="default: both")
    parser.add_argument("--out", type=Path, default=None, help="JSON path (default: next to the checkpoint)")
    args = parser.parse_args(argv)
    try:
        loaded = load_separator(args.checkpoint)
        library = SoundLibrary.load()
        results, started = {}, time.perf_counter()
        for split in args.sound_split or SOUND_SPLITS:
            episodes = episodes_for(EpisodeConfig(task=args.task, scene_split="test", sound_split=split), library)
            results[split] = summarize(evaluate_passive(loaded, episodes[: args.count], library))
    except M2HError as exc:
        print(f"eval_passive: error: {exc}", file=sys.stderr)
        return 2
    print(format_table(results))
    out = args.out or args.checkpoint.with_name(f"{args.checkpoint.stem}_passive.json")
    document = {"command": shlex.join(["scripts/eval_passive.py", *(sys.argv[1:] if argv is None else argv)]),
                "checkpoint": str(args.checkpoint), "task": args.task, "scene_split": "test", "step": 0,
                "count_per_split": args.count, "wall_seconds": round(time.perf_counter() - started, 1),
                "references": REFERENCES,
                "results": results}
    out.write_text(json.dumps(document, indent=1) + "\n")
    print(f"wrote {out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
