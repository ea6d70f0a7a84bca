#!/usr/bin/env python3
"""Experiment 4 of the supplementary material: separation scenarios S-vs-S, S-vs-M, S-vs-B, M-vs-B.

    python scripts/experiments/scenarios.py [--scenarios S-vs-S,S-vs-M,S-vs-B,M-vs-B] [--sound-split heard,unheard]
        [--controllers stand_in_place,move2hear_quality] [--count 200] [--workers 2] [--address ADDR]
        [--out runs/experiments/scenarios]

Near-target test episodes whose target and distractor are of the given categories (S speech, M
music, B background); each controller plays the first ``--count`` of each. The paper's finding
(Supp. Sec. 5): speech against speech is the hardest, and moving helps in every scenario.
"""

import os
import sys

os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")

from m2h_ros.experiments.cli import sweep_main  # noqa: E402
from m2h_ros.experiments.sweep import Condition  # noqa: E402


def conditions(args):
    return [Condition(label=name, x=name, episodes={"scenario": name}) for name in args.scenarios.split(",")]


if __name__ == "__main__":
    sys.exit(sweep_main(None, script=__file__, doc=__doc__, conditions=conditions,
                        title="Final-step SI-SDR per separation scenario", xlabel="scenario (target vs distractor)",
                        add_arguments=lambda p: p.add_argument("--scenarios", default="S-vs-S,S-vs-M,S-vs-B,M-vs-B")))
