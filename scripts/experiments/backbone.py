#!/usr/bin/env python3
"""Experiment 5 of the supplementary material: a stronger passive backbone (MMDenseNet-style), with and without motion.

    python scripts/experiments/backbone.py [--unet runs/backbone/unet_equal_budget.pt]
        [--mmdensenet runs/backbone/mmdensenet.pt] [--controllers stand_in_place,doa,move2hear_quality]
        [--sound-split heard,unheard] [--count 200] [--workers 2] [--address ADDR] [--out runs/experiments/backbone]

Three separators, each a condition: the shipped compact U-Net (``m2h_ros/models/default``), a compact
U-Net trained with the experiment's smaller budget, and the MMDenseNet-style separator trained with
the same budget, seed and data stream (``docs/design/separator_training.md``; the commands that
train them: docs/results/experiments/backbone/README.md). Each controller plays the first ``--count`` near-target test episodes of each
sound split with each separator: Stand In-Place (no motion), DoA (the best training-free mover)
and the shipped pi^Q (trained on the shipped separator's outputs). The report adds every controller's
paired difference to Stand In-Place, and every separator's to the equal-budget U-Net. The paper's
finding (Supp. Sec. 3): a stronger backbone raises quality, and motion still adds on top of it.
"""

import os
import sys
from pathlib import Path

os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")

from m2h_ros.experiments.cli import sweep_main  # noqa: E402
from m2h_ros.experiments.sweep import Condition  # noqa: E402
from m2h_ros.models.checkpoint import load_separator  # noqa: E402
from m2h_ros.paths import REPO_DIR  # noqa: E402

TRAINED = REPO_DIR / "runs" / "backbone"
EQUAL_BUDGET_UNET = "U-Net, equal budget"


def _checked(path: Path) -> str:
    """An absolute checkpoint path (Ray workers run elsewhere), loaded once here so a missing or
    foreign file fails before any job runs."""
    path = path if path.is_absolute() else REPO_DIR / path
    load_separator(path)
    return str(path)


def conditions(args):
    return [Condition(label="U-Net, shipped", x="U-Net shipped"),
            Condition(label=EQUAL_BUDGET_UNET, x="U-Net equal", separator=_checked(args.unet)),
            Condition(label="MMDenseNet, equal budget", x="MMDenseNet", separator=_checked(args.mmdensenet))]


def add_arguments(parser):
    parser.add_argument("--unet", type=Path, default=TRAINED / "unet_equal_budget.pt",
                        help="the U-Net trained with the experiment's budget")
    parser.add_argument("--mmdensenet", type=Path, default=TRAINED / "mmdensenet.pt",
                        help="the MMDenseNet-style separator trained with the same budget")


if __name__ == "__main__":
    sys.exit(sweep_main(None, script=__file__, doc=__doc__, conditions=conditions, add_arguments=add_arguments,
                        title="Passive backbone: final-step SI-SDR per separator, with and without motion",
                        xlabel="separator (f^B, f^M backbone)", controllers="stand_in_place,doa,move2hear_quality",
                        reference="stand_in_place", condition_reference=EQUAL_BUDGET_UNET))
