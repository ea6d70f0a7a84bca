#!/usr/bin/env python3
"""Experiment 3 of the supplementary material: the composite policy's switch time T^N (far-target).

    python scripts/experiments/switch_time.py [--switch-steps 0,20,40,60,80,100] [--sound-split heard,unheard]
        [--scene-split test] [--count 200] [--workers 2] [--address ADDR] [--out runs/experiments/switch_time]

Move2Hear on far-target test episodes walks until step T^N, then improves the estimate with pi^Q
(``move2hear``'s ``switch_step``); 100 is "no switch" (the walker throughout; the episode has 100 steps), 0
is pi^Q throughout. Each T^N is also compared with the default's (100) on the same episodes. ``move2hear``
walks with pi^N + Stop, whose Stop ends the episode; ``--controllers move2hear:approach`` with the approach
policy (no Stop, as the original's composite: every episode runs to step 100; its T^N is 80, the original's).
Pick T^N on the validation split: ``--scene-split val`` (100 was chosen for pi^N + Stop, 400 episodes
per split against 80; docs/design/policies.md). The paper's finding (Supp. Sec. 4): switching late enough to reach
the target, early enough to refine there, beats both extremes. Needs the shipped pi^Q and pi^N (docs/design/policies.md).
"""

import os
import sys

os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")

from m2h_ros.agents.learned import DEFAULT_SWITCH_STEPS  # noqa: E402
from m2h_ros.experiments.cli import switch_step_main  # noqa: E402

if __name__ == "__main__":
    sys.exit(switch_step_main(script=__file__, doc=__doc__, option="switch_step", symbol="T^N", task="far_target",
                              steps="0,20,40,60,80,100", reference_step=DEFAULT_SWITCH_STEPS["ends"], scene_split="test",
                              title="Far-target final-step SI-SDR vs the switch step T^N",
                              xlabel="switch step T^N (pi^N before, pi^Q after)"))
