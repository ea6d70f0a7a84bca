"""``m2h-eval``: score recorded runs offline from their rosbag2 MCAP bags and check the live scores.

``m2h-eval runs/a runs/b --out eval/`` replays each bag (ours, or one of the same topics from
``ros2 bag record -s mcap``; a bag whose recorder was killed is read up to its last complete chunk) on
every core available, recomputes every step's SI-SDR (ground-truth phase and mixture phase), STFT distance, SR and SPL from the
recorded estimates and ground truth, compares them with the scores the live evaluator recorded, and
writes results.{md,csv,json}, comparison.{md,csv} and the SI-SDR-vs-step plots into ``--out``.

Exit status: 0 all scored and equal to the live scores; 1 a live score differs beyond ``--atol``;
3 a bag is damaged or foreign, or an episode could not be scored (what could be scored is written);
2 bad options or no bag could be read at all.
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence
from pathlib import Path

from m2h_ros.core.results import markdown_table, summarize
from m2h_ros.core.world.worlds import load_world
from m2h_ros.errors import BagError, ConfigError
from m2h_ros.io.replay import BagReplay, ReplayConfig, available_cores, replay_bags, write_replay

EXIT_MISMATCH, EXIT_FATAL, EXIT_PROBLEMS = 1, 2, 3


def build_parser() -> argparse.ArgumentParser:
    defaults = ReplayConfig()
    paragraphs = __doc__.split("\n\n")
    exit_status = next(p for p in paragraphs if p.startswith("Exit status")).replace("``", "")
    parser = argparse.ArgumentParser(prog="m2h-eval", description=paragraphs[0].split(": ", 1)[1], epilog=exit_status)
    parser.add_argument("bags", nargs="+", type=Path, help="rosbag2 bag directories (or .mcap files)")
    parser.add_argument("--out", type=Path, default=Path("m2h-eval"), help="output folder (default: m2h-eval)")
    parser.add_argument("--namespace", default=defaults.namespace,
                        help=f"namespace the graph ran in (default: {defaults.namespace})")
    parser.add_argument("--atol", type=float, default=defaults.atol,
                        help=f"tolerance of replayed vs live scores (default: {defaults.atol:g})")
    parser.add_argument("--workers", type=int, default=available_cores(),
                        help="processes: with as many bags, that many bags at once; with fewer, each bag read once "
                             "and its steps scored by that many (same output; default: the cores available, "
                             f"{available_cores()} here)")
    parser.add_argument("--no-plots", action="store_true", help="write tables only")
    parser.add_argument("--world", default="", metavar="SPEC",
                        help="the imported world the runs should have played in (map:PATH/map.yaml or mesh:PATH): "
                             "an episode recorded in another world, or another version of it, is a problem")
    return parser


def check_world(replay: BagReplay, world_id: str, spec: str) -> None:
    """A problem for every episode of the bag recorded in another world than ``world_id`` (``spec``'s)."""
    for result in replay.results:
        if result.scene_id != world_id:
            replay.problems.append(BagError(
                f"{replay.bag}: episode {result.episode_id} was recorded in world {result.scene_id}, not in "
                f"{world_id} ({spec}): scored against another world"))


def _one_line(text: str) -> str:
    return " ".join(str(text).split())


def main(argv: Sequence[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    try:
        config = ReplayConfig(namespace=args.namespace, atol=args.atol)
        in_order = replay_bags(args.bags, config=config, workers=args.workers)
    except ConfigError as exc:
        print(f"m2h-eval: error: {_one_line(exc)}", file=sys.stderr)
        return EXIT_FATAL
    try:
        world = load_world(args.world).world_id if args.world else ""
    except ConfigError as exc:
        print(f"m2h-eval: error: {_one_line(exc)}", file=sys.stderr)
        return EXIT_FATAL
    replays: list[BagReplay] = []
    unreadable = 0
    for bag, replay in zip(args.bags, in_order, strict=True):
        if isinstance(replay, BagError):
            print(f"m2h-eval: error: {_one_line(replay)}", file=sys.stderr)
            unreadable += 1
            continue
        if world:
            check_world(replay, world, args.world)
        replays.append(replay)
        c = replay.comparison
        print(f"{bag}: {len(replay.results)} episode(s), {replay.steps_scored} step(s) scored; "
              f"compared with live: {c.steps} step(s), {c.episodes} episode(s), {len(c.mismatches)} mismatch(es) "
              f"(atol {config.atol:g})")
        for m in c.mismatches[:10]:
            where = "episode" if m.step is None else f"step {m.step}"
            print(f"  differs: {m.episode_id} {where} {m.metric}: live {m.live:.6g}, replayed {m.replayed:.6g}")
        for problem in replay.problems:
            print(f"  problem: {_one_line(problem)}")
        for note in replay.notes:
            print(f"  note: {note}")
    if not replays:
        return EXIT_FATAL
    paths = write_replay(replays, args.out, atol=config.atol, plot=not args.no_plots)
    results = [r for replay in replays for r in replay.results]
    if results:
        print(markdown_table(summarize(results)), end="")
    print(f"tables: {paths['markdown']} {paths['csv']} {paths['json']}; comparison: {paths['comparison']}"
          + (f"; plot: {paths['plot']}" if "plot" in paths else ""))
    if any(r.comparison.mismatches for r in replays):
        return EXIT_MISMATCH
    if unreadable or any(r.problems for r in replays):
        return EXIT_PROBLEMS
    return 0


if __name__ == "__main__":
    sys.exit(main())
