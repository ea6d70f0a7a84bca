#!/usr/bin/env python3
"""Passive separation on the held-out test episodes: floor (mixture), separator and ideal-mask oracle.

    python scripts/eval_passive.py [--checkpoint m2h_ros/models/default/separator_compact.pt] [--count 500]
                                   [--head kemar | sofa:PATH | free_field:SPACING_M]

Stand In-Place at step 0 of near-target test episodes (heard and unheard sounds; the first --count
episodes of the standard 1000-episode files), f^B + f^M + f^R with fresh memory; definitions in
``m2h_ros/training/passive_eval.py``. Prints a table and the share of the floor-to-oracle gap the
separator closes, and writes JSON (default: <checkpoint stem>_passive.json next to the checkpoint)
with every episode's scores. ``--paired-with OTHER.json`` (another separator's JSON from this command,
same episodes and head) adds the paired difference of the separator's scores, this one minus that one.
"""

from __future__ import annotations

import argparse
import json
import shlex
import sys
import time
from pathlib import Path

import numpy as np

from m2h_ros.core.audio.scoring import DEPLOYABLE_REFERENCE
from m2h_ros.core.results import METRIC_LABELS, METRICS, mean_sem
from m2h_ros.core.sounds.library import SoundLibrary
from m2h_ros.core.world.acoustics import BACKENDS, BACKEND_HELP, AcousticsConfig
from m2h_ros.core.world.env import EnvConfig
from m2h_ros.core.world.hrtf import HEAD_HELP, KEMAR
from m2h_ros.core.world.episodes import SOUND_SPLITS, TASKS, EpisodeConfig, episodes_for
from m2h_ros.errors import ConfigError, reports_errors
from m2h_ros.models.checkpoint import DEFAULT_SEPARATOR_CHECKPOINT, load_separator
from m2h_ros.paths import repo_relative
from m2h_ros.training.passive_eval import ESTIMATES, evaluate_passive, gap_closed, summarize

LABELS = {"mixture": "mixture (floor)", "separator": "separator (refined)",
          "separator_binaural": "f^B ear mean", "oracle": "ideal mask (oracle)"}
GAP_ESTIMATES = ("separator", "separator_binaural")
REFERENCES = {"si_sdr": "dry target", "si_sdr_mixture_phase": DEPLOYABLE_REFERENCE, "stft_distance": "dry target"}


def format_table(results: dict[str, dict]) -> str:
    lines = [f"{'sounds':<8} {'estimate':<24} " + " ".join(f"{METRIC_LABELS[m]:>28}" for m in METRICS) + f" {'n':>5}"]
    for split, result in results.items():
        for estimate in ESTIMATES:
            s = result["summary"][estimate]
            cells = " ".join(f"{s[m]:>19.2f} ± {s[m + '_sem']:<6.2f}" for m in METRICS)
            lines.append(f"{split:<8} {LABELS[estimate]:<24} {cells} {s['episodes']:>5}")
        for estimate in GAP_ESTIMATES:
            gap = result["gap_closed"][estimate]
            lines.append(f"{split:<8} {'gap: ' + LABELS[estimate]:<24} " + " ".join(f"{gap[m]:>27.0%} " for m in METRICS))
    return "\n".join(lines)


def paired_difference(results: dict[str, dict], args: argparse.Namespace) -> None:
    """Add ``paired`` to each split: mean and standard error of (this separator - the other one's) per
    episode, for the separator's estimates; printed too."""
    other = json.loads(args.paired_with.read_text())
    for key, mine in (("task", args.task), ("count_per_split", args.count), ("head", args.head)):
        if other.get(key) != mine:
            raise ConfigError(f"--paired-with {args.paired_with}: its {key} is {other.get(key)!r}, this run's {mine!r}")
    for split, result in results.items():
        theirs = other["results"].get(split, {}).get("per_episode")
        if theirs is None:
            raise ConfigError(f"--paired-with {args.paired_with} has no per-episode {split} scores")
        paired = {"with": repo_relative(args.paired_with), "checkpoint": other["checkpoint"]}
        for estimate in GAP_ESTIMATES:
            paired[estimate] = {}
            for metric in METRICS:
                mean, sem = mean_sem(np.subtract(result["per_episode"][estimate][metric], theirs[estimate][metric]))
                paired[estimate][metric] = {"mean": mean, "sem": sem}
        result["paired"] = paired
        si_sdr = paired["separator"]["si_sdr"]
        print(f"{split:<8} paired: {LABELS['separator']} minus {other['checkpoint']}'s, SI-SDR (GT phase) "
              f"{si_sdr['mean']:+.2f} ± {si_sdr['sem']:.2f} dB (mean ± standard error)")


@reports_errors("eval_passive")
def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--checkpoint", type=Path, default=DEFAULT_SEPARATOR_CHECKPOINT)
    parser.add_argument("--count", type=int, default=500, help="episodes per sound split")
    parser.add_argument("--task", choices=TASKS, default="near_target")
    parser.add_argument("--sound-split", choices=SOUND_SPLITS, action="append", help="default: both")
    parser.add_argument("--out", type=Path, default=None, help="JSON path (default: next to the checkpoint)")
    parser.add_argument("--head", default=KEMAR, help=HEAD_HELP)
    parser.add_argument("--acoustics-backend", default="project", choices=BACKENDS, help=BACKEND_HELP)
    parser.add_argument("--paired-with", type=Path, default=None,
                        help="JSON of another separator on the same episodes and head: add the paired difference")
    args = parser.parse_args(argv)
    env_config = EnvConfig(camera=False, acoustics=AcousticsConfig(head=args.head, backend=args.acoustics_backend))
    loaded = load_separator(args.checkpoint)
    library = SoundLibrary.load()
    results, started = {}, time.perf_counter()
    for split in args.sound_split or SOUND_SPLITS:
        episodes = episodes_for(EpisodeConfig(task=args.task, scene_split="test", sound_split=split), library)
        scores = evaluate_passive(loaded, episodes[: args.count], library, env_config=env_config)
        summary = summarize(scores)
        results[split] = {"summary": summary, "gap_closed": {e: {m: gap_closed(summary, m, e) for m in METRICS}
                                                              for e in GAP_ESTIMATES},
                          "per_episode": {e: {m: [round(float(v), 4) for v in values] for m, values in metrics.items()}
                                          for e, metrics in scores.items()}}
    print(format_table(results))
    if args.paired_with:
        paired_difference(results, args)
    out = args.out or args.checkpoint.with_name(f"{args.checkpoint.stem}_passive.json")
    given = sys.argv[1:] if argv is None else argv
    document = {"command": shlex.join(["scripts/eval_passive.py", *given]),
                "checkpoint": repo_relative(args.checkpoint), "head": args.head,
                "acoustics": env_config.acoustics.digest(), "task": args.task, "scene_split": "test", "step": 0,
                "count_per_split": args.count, "wall_seconds": round(time.perf_counter() - started, 1),
                "estimates": {"mixture": "|STFT| of the ear-mean mixture (do nothing)",
                              "separator": "f^B -> f^M -> f^R, fresh memory (estimate of the dry target)",
                              "separator_binaural": "ear mean of f^B's separated binaural (the target as heard)",
                              "oracle": "ideal mask: min(|R|, |X|), X = STFT of the ear-mean mixture, R = STFT "
                                        "of the metric's reference: the dry target (GT-phase SI-SDR, STFT "
                                        "distance), the target as heard / number of sources (mixture phase)"},
                "references": REFERENCES,
                "results": results}
    out.write_text(json.dumps(document, indent=1) + "\n")
    print(f"wrote {repo_relative(out)}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
