"""``m2h-derive``: add to recorded bags the topics derived from their raw ones (spectrogram pictures,
pcm-s16 tracks, the path, TF), which the recorder leaves out unless keep_derived is true.

m2h-derive runs/demo/bag rewrites the bag in place (--out writes a new one instead); Foxglove, rviz and
ros2 bag play then see what a recording with keep_derived true holds. scripts/run_pipeline.py runs it
after every recorded run.

Exit status: 0 every bag done; 2 bad options or a bag that cannot be read or written.
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence
from pathlib import Path

from m2h_ros.errors import BagError
from m2h_ros.io.derive_bag import derive_bag


def build_parser() -> argparse.ArgumentParser:
    paragraphs = __doc__.split("\n\n")
    parser = argparse.ArgumentParser(prog="m2h-derive", description=paragraphs[0].split(": ", 1)[1],
                                     epilog=paragraphs[-1])
    parser.add_argument("bags", nargs="+", type=Path, help="rosbag2 bag directories")
    parser.add_argument("--out", type=Path, default=None,
                        help="write the result here instead of rewriting the bag (one bag only)")
    parser.add_argument("--namespace", default="/", help="namespace the graph ran in (default: /)")
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    if args.out is not None and len(args.bags) > 1:
        parser.error("--out takes one bag")
    for bag in args.bags:
        try:
            print(derive_bag(bag, namespace=args.namespace, out=args.out).summary, flush=True)
        except BagError as exc:
            print(f"m2h-derive: error: {' '.join(str(exc).split())}", file=sys.stderr)
            return 2
    return 0


if __name__ == "__main__":
    sys.exit(main())
