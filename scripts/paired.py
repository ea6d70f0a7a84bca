#!/usr/bin/env python3
"""Paired comparisons from evaluation results already written: each controller minus a reference's
final-step score on the same episodes, mean and 95% CI per task and sound split (``--metric success`` /
``spl``: far-target navigation's, episode by episode: a paired SR / SPL difference). No episode is played
again.

    python scripts/paired.py docs/results/near_target/results.csv --reference doa,stand_in_place \
        [--metric si_sdr|si_sdr_mixture_phase|stft_distance|success|spl] [--out paired.md] [--png paired.png]
    python scripts/paired.py shipped/results.json candidate/results.json --tags shipped,candidate \
        --reference move2hear:shipped
    python scripts/paired.py docs/results/near_target/results.csv --reference stand_in_place \
        --controllers stand_in_place,move2hear --count 200

Several results files (``results.json`` of ``scripts/evaluate.py``, the evaluator node or ``m2h-eval``)
are read as one set, so runs of the same episodes compare too. A ``results.csv`` (what ``docs/results/``
keeps in git; its results.json is not) holds the final-step scores alone, which is all a paired
comparison needs. A controller that played an episode in two files counts once if both runs agree (the
same actions and scores, or the same final scores to the CSV's 6 decimals where one file is a CSV; e.g.
the reference evaluated beside each). Where they differ (say, two policy checkpoints behind one name),
``--tags`` names each file's run: that controller becomes ``<controller>:<tag>`` per file; without tags
it is an error. Controllers that agree keep their name (``<controller>:<tag>`` still finds them as a
reference). A sweep's episodes (``scripts/experiments/*``: a ``condition`` each) count as one controller per
condition, ``<controller>[<condition>]`` (e.g. ``move2hear[T = 20]``), tagged after it.
``--controllers`` keeps those controllers and ``--count N`` each task and sound split's first N episodes (by
episode id, the ones ``evaluate.py --count N`` plays): a larger run's figures on a smaller run's episodes.
``--png`` draws the differences as a forest plot (one panel per reference and task, each controller's
mean and 95% CI per sound split).
"""

from __future__ import annotations

import argparse
import shlex
import sys
from pathlib import Path

from m2h_ros.core.results import (METRICS, PAIRED_METRICS, EpisodeResult, paired_differences, paired_section, plot_paired,
                                  read_final_scores, read_results)
from m2h_ros.errors import ConfigError, reports_errors


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("results", nargs="+", type=Path, help="results.json (or results.csv) files")
    parser.add_argument("--reference", required=True, help="controller(s) to compare with, comma-separated")
    parser.add_argument("--tags", default="", help="one name per results file, comma-separated: its "
                        "controllers become <controller>:<tag>")
    parser.add_argument("--metric", choices=PAIRED_METRICS, default="si_sdr",
                        help="a final-step score, or far-target navigation's success (paired SR) or SPL")
    parser.add_argument("--controllers", default="", help="only these controllers, comma-separated (default: all)")
    parser.add_argument("--count", type=int, default=None,
                        help="only each task and sound split's first COUNT episodes, by episode id")
    parser.add_argument("--out", type=Path, default=None, help="also write the tables to this Markdown file")
    parser.add_argument("--png", type=Path, default=None, help="also draw the differences as a forest plot")
    return parser


def load(paths: list[Path], tags: list[str]) -> list[EpisodeResult]:
    if tags and len(tags) != len(paths):
        raise ConfigError(f"--tags names {len(tags)} runs for {len(paths)} results files")
    runs = [read_final_scores(path) if path.suffix == ".csv" else read_results(path) for path in paths]
    for run in runs:
        for result in run:
            if result.condition:  # a sweep's conditions are its controllers here
                result.controller = f"{result.controller}[{result.condition}]"
    if tags:
        differing = _differing(runs)
        for tag, run in zip(tags, runs, strict=True):
            for result in run:
                if result.controller in differing:
                    result.controller = f"{result.controller}:{tag}"
    results, seen = [], {}
    for path, run in zip(paths, runs, strict=True):
        for result in run:
            key = _key(result)
            if key in seen:
                first_path, first = seen[key]
                if not _same_play(result, first):
                    raise ConfigError(f"{result.controller} played episode {result.episode_id} differently in "
                                      f"{first_path} and {path} (two runs of it: name them with --tags)")
                continue
            seen[key] = path, result
            results.append(result)
    return results


def selected(results: list[EpisodeResult], controllers: list[str], count: int | None) -> list[EpisodeResult]:
    """The results of ``controllers`` (all if empty) on each task and sound split's first ``count`` episodes."""
    if count is not None and count < 1:
        raise ConfigError(f"--count {count} must be at least 1")
    known = {r.controller for r in results}
    unknown = [c for c in controllers if c not in known]
    if unknown:
        raise ConfigError(f"--controllers names {', '.join(unknown)}, not in the results; they hold "
                          f"{', '.join(sorted(known))}")
    if controllers:
        results = [r for r in results if r.controller in controllers]
    if count is None:
        return results
    first: dict[tuple[str, str], set[str]] = {}
    for task, split in {(r.task, r.sound_split) for r in results}:
        ids = sorted({r.episode_id for r in results if (r.task, r.sound_split) == (task, split)})
        first[task, split] = set(ids[:count])
    return [r for r in results if r.episode_id in first[r.task, r.sound_split]]


def _key(result: EpisodeResult) -> tuple[str, str, str, str]:
    return result.controller, result.task, result.sound_split, result.episode_id


def _same_play(a: EpisodeResult, b: EpisodeResult) -> bool:
    """The same episode played alike: equal results, or equal final scores where one came from a CSV."""
    if bool(a.actions) == bool(b.actions):  # both from JSON, or both from CSV
        return a == b
    return a.success == b.success and all(abs(a.final(m) - b.final(m)) <= 1e-6 * max(1.0, abs(b.final(m)))
                                          for m in METRICS)


def _differing(runs: list[list[EpisodeResult]]) -> set[str]:
    """Controllers that played some episode differently in two runs."""
    seen, differing = {}, set()
    for run in runs:
        for result in run:
            first = seen.setdefault(_key(result), result)
            if not _same_play(result, first):
                differing.add(result.controller)
    return differing


def differences(results: list[EpisodeResult], references: list[str], metric: str) -> dict[str, list[dict]]:
    """``paired_differences`` rows per reference."""
    controllers = sorted({r.controller for r in results})
    by_reference = {}
    for reference in references:
        plain = reference.rpartition(":")[0]
        if reference not in controllers and plain in controllers:   # tagged, but it agreed in every run
            reference = plain
        if reference not in controllers:
            raise ConfigError(f"reference {reference!r} is not in the results; they hold {', '.join(controllers)}")
        by_reference[reference] = paired_differences(results, reference=reference, metric=metric)
    return by_reference


@reports_errors("paired")
def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    command = shlex.join(["python", "scripts/paired.py", *(sys.argv[1:] if argv is None else argv)])
    tags = [t for t in args.tags.split(",") if t]
    results = selected(load(args.results, tags), [c for c in args.controllers.split(",") if c], args.count)
    rows = differences(results, [r for r in args.reference.split(",") if r], args.metric)
    if args.png:
        plot_paired([row for per_reference in rows.values() for row in per_reference], args.png)
    text = "\n".join(paired_section(r, reference=ref, metric=args.metric) for ref, r in rows.items())
    print(text, end="")
    if args.png:
        print(f"plot: {args.png}")
    if args.out:
        args.out.write_text(f"Command: `{command}`\n\n{text}")
        print(f"markdown: {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
