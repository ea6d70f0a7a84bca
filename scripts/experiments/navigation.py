#!/usr/bin/env python3
"""Experiment 7 of the supplementary material: navigation to the target among distractors (SR, SPL).

    python scripts/experiments/navigation.py [--controllers random,move_forward,gan_et_al,av_navigator,move2hear_navigation]
        [--sound-split heard] [--count 100] [--workers 2] [--address ADDR] [--out runs/experiments/navigation]

Far-target test episodes; each controller must reach the target's node and Stop there (success);
SPL weighs a success by shortest path / path taken. Two splits: *standard* (any target and
distractor, the episode files' mix) and *speaker-target* (a speech target among speech distractors,
S-vs-S: the distractor sounds like the target). The paper's finding: Move2Hear's pi^N + Stop
navigates best (SR 70.3, SPL 54.9 on the standard split, heard sounds).
"""

import os
import sys

os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")

from m2h_ros.experiments.cli import sweep_main  # noqa: E402
from m2h_ros.experiments.sweep import Condition  # noqa: E402

SPLITS = {"standard": "any", "speaker-target": "S-vs-S"}


def conditions(args):
    return [Condition(label=name, x=name, episodes={"scenario": scenario}) for name, scenario in SPLITS.items()]


if __name__ == "__main__":
    sys.exit(sweep_main(None, script=__file__, doc=__doc__, conditions=conditions,
                        controllers="random,move_forward,gan_et_al,av_navigator,move2hear_navigation", task="far_target",
                        sound_split="heard", title="Far-target navigation among distractors",
                        xlabel="split (standard: any sounds; speaker-target: speech vs speech)"))
