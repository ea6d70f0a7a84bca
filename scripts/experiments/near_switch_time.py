#!/usr/bin/env python3
"""Near-target Move2Hear that first walks with the approach policy, then improves the estimate with pi^Q.

    python scripts/experiments/near_switch_time.py [--switch-steps 0,5,10,20] [--scene-split val]
        [--count 200] [--workers 2] [--policy-checkpoint FOLDER] [--out DIR]

``move2hear``'s ``near_switch_step`` T: near-target, the folder's approach policy (``policy_approach.pt``,
three actions, trained on the geodesic distance gained) acts until step T, then pi^Q with a fresh GRU state,
as the far-target composite switches at T^N. T = 0 is the paper's near-target Move2Hear (pi^Q throughout,
the default); 20 is the approach policy throughout (a near-target episode has 20 actions). Each T is
compared with T = 0 on the same episodes. Choose on the validation split (``--scene-split val``), report on
test. Why (docs/design/policies.md): pi^Q separates as well as a privileged walk to the target
where it ends on the target's node, and misses the node in about 45% of its walks.
"""

import os
import sys

os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")

from m2h_ros.experiments.cli import switch_step_main  # noqa: E402

if __name__ == "__main__":
    sys.exit(switch_step_main(script=__file__, doc=__doc__, option="near_switch_step", symbol="T", task="near_target",
                              steps="0,5,10,20", reference_step=0, scene_split="val",
                              title="Near-target final-step SI-SDR vs the approach policy's steps T",
                              xlabel="near-target switch step T (approach policy before, pi^Q after)"))
