#!/usr/bin/env python3
"""Choose the Gan et al. baseline's Stop rule on the validation split (far-target).

    python scripts/experiments/gan_stop_rule.py [--thresholds 0.5,0.7,0.9] [--patience 1,2]
        [--sound-split unheard] [--count 48] [--out DIR]

The controller stops when the sound locator's Stop probability has exceeded the threshold on
``patience`` consecutive steps (``m2h_ros/agents/gan.py``). Each (threshold, patience) plays the
same far-target episodes of the val scenes; the table gives SR, SPL and the final SI-SDR per rule.
"""

import itertools
import os
import sys

os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")

from m2h_ros.experiments.cli import sweep_main  # noqa: E402
from m2h_ros.experiments.sweep import Condition  # noqa: E402


def conditions(args):
    thresholds = [float(v) for v in args.thresholds.split(",")]
    patience = [int(v) for v in args.patience.split(",")]
    return [Condition(label=f"p > {t:g} x {k}", x=f"{t:g} x {k}", episodes={"scene_split": "val"},
                      controller={"stop_threshold": t, "stop_patience": k})
            for t, k in itertools.product(thresholds, patience)]


def arguments(parser):
    parser.add_argument("--thresholds", default="0.5,0.7,0.9")
    parser.add_argument("--patience", default="1,2")


if __name__ == "__main__":
    sys.exit(sweep_main(None, script=__file__, doc=__doc__, conditions=conditions, controllers="gan_et_al",
                        task="far_target", title="Gan et al. on val far-target episodes, by Stop rule",
                        xlabel="Stop rule (probability threshold x consecutive steps)", add_arguments=arguments))
