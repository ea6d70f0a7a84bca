#!/usr/bin/env python3
"""Choose ``move2hear_navigation:confirm``'s threshold on the validation split (far-target).

    python scripts/experiments/confirm_stop.py [--thresholds 0,0.3,0.5,0.7] [--sound-split heard,unheard]
        [--count 200] [--workers 2] [--out DIR]

pi^N + Stop takes its Stop only where the supervised Stop predictor of Gan et al.'s sound locator gives
the robot at least the threshold's probability of standing on the target's node; elsewhere Stop's
probability is dropped and the rest renormalised (``m2h_ros/agents/learned.py``). 0 is pi^N + Stop as
trained. Each threshold plays the same far-target episodes of the val scenes, paired with 0's; the table
gives SR, SPL and the final SI-SDR. Needs the shipped pi^N + Stop and locator.
"""

import os
import sys

os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")

from m2h_ros.experiments.cli import sweep_main  # noqa: E402
from m2h_ros.experiments.sweep import Condition  # noqa: E402


def label(threshold: float) -> str:
    return f"confirm p >= {threshold:g}" if threshold else "no check"


def conditions(args):
    return [Condition(label=label(t), x=t, episodes={"scene_split": "val"}, controller={"confirm_stop": t})
            for t in (float(v) for v in args.thresholds.split(","))]


def arguments(parser):
    parser.add_argument("--thresholds", default="0,0.3,0.5,0.7")


if __name__ == "__main__":
    sys.exit(sweep_main(None, script=__file__, doc=__doc__, conditions=conditions, controllers="move2hear_navigation",
                        task="far_target", sound_split="heard,unheard",
                        title="pi^N + Stop on val far-target episodes, Stop confirmed by the locator",
                        xlabel="Stop predictor's probability needed for pi^N's Stop (0: no check)",
                        add_arguments=arguments, condition_reference=label(0.0)))
