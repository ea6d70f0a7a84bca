#!/usr/bin/env python3
"""Experiment 1 of the supplementary material: separation quality vs microphone noise, with and without f^R.

    python scripts/experiments/noise_robustness.py [--levels 0,0.05,0.1,0.2] [--task near_target,far_target]
        [--sound-split heard,unheard] [--controllers stand_in_place,move2hear_quality] [--count 200]
        [--workers 2] [--address ADDR] [--out runs/experiments/noise_robustness]

Each controller plays the first ``--count`` test episodes of each task x sound split at each
microphone noise level (white noise per ear, std = level x the clean mixture's RMS: 0.05 / 0.1 / 0.2
are SNR 26 / 20 / 14 dB, the levels the separator was trained with), scored on the refined estimate
(f^R) and, in a second play of the same episodes, on f^M's (no f^R); the report pairs the two on the same
episodes (f^R's gain per controller and level) and each controller with Stand In-Place. Jobs run on Ray; the table
does not depend on ``--workers``. The paper's finding (Supp. Sec. 2): quality falls with noise and
f^R's memory makes Move2Hear more robust to it.
"""

import os
import sys

os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")

from m2h_ros.experiments.cli import sweep_main  # noqa: E402
from m2h_ros.experiments.sweep import Condition, with_estimates  # noqa: E402


def conditions(args):
    levels = [float(v) for v in args.levels.split(",")]
    return with_estimates([Condition(label=f"mic noise {v:g}", x=v, env={"mic_noise": v}) for v in levels])


if __name__ == "__main__":
    sys.exit(sweep_main(None, script=__file__, doc=__doc__, conditions=conditions,
                        title="Noise robustness: final-step SI-SDR vs microphone noise",
                        xlabel="microphone noise (std / mixture RMS)",
                        add_arguments=lambda p: p.add_argument("--levels", default="0,0.05,0.1,0.2")))
