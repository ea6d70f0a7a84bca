#!/usr/bin/env python3
"""Near-target Move2Hear that first walks with the approach policy, then improves the estimate with pi^Q.

    python scripts/experiments/near_switch_time.py [--switch-steps 0,5,10,20] [--scene-split val]
        [--count 200] [--workers 2] [--policy-checkpoint FOLDER] [--out docs/results/near_switch_time]

``move2hear``'s ``near_switch_step`` T: near-target, the folder's approach policy (``policy_approach.pt``,
three actions, trained on the geodesic distance gained) acts until step T, then pi^Q with a fresh GRU state,
as the far-target composite switches at T^N. T = 0 is the paper's near-target Move2Hear (pi^Q throughout,
the default); 20 is the approach policy throughout (a near-target episode has 20 actions). Each T is
compared with T = 0 on the same episodes. Choose on the validation split (``--scene-split val``), report on
test. Why (docs/policies.md, sessions 20-26): pi^Q separates as well as a privileged walk to the target
where it ends on the target's node, and misses the node in about 45% of its walks.
"""

import os
import sys

os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")

from m2h_ros.experiments.cli import sweep_main  # noqa: E402
from m2h_ros.experiments.sweep import Condition  # noqa: E402


def label(switch_step: int) -> str:
    return f"T = {switch_step}"


def conditions(args):
    steps = [int(v) for v in args.switch_steps.split(",")]
    return [Condition(label=label(t), x=t, controller={"near_switch_step": t},
                      episodes={"scene_split": args.scene_split}) for t in steps]


def arguments(parser):
    parser.add_argument("--switch-steps", default="0,5,10,20")
    parser.add_argument("--scene-split", default="val", choices=("val", "test"),
                        help="val to choose T, test to report it")


if __name__ == "__main__":
    sys.exit(sweep_main(None, script=__file__, doc=__doc__, conditions=conditions, controllers="move2hear",
                        task="near_target", title="Near-target final-step SI-SDR vs the approach policy's steps T",
                        xlabel="near-target switch step T (approach policy before, pi^Q after)",
                        add_arguments=arguments, condition_reference=label(0)))
