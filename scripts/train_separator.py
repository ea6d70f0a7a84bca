#!/usr/bin/env python3
"""Pretrain the passive separator and write the checkpoint, its metadata JSON and loss curve PNG.

    python scripts/train_separator.py --preset compact --seed 0 --out m2h_ros/models/default/separator_compact_pretrained.pt

(the shipped separator_compact.pt is that one with f^R trained beside pi^Q: scripts/train_shipped.sh refiner)

Same as ``python -m m2h_ros.training.pretrain_separator``; see that module for the stages and losses.
"""

import sys

from m2h_ros.training.pretrain_separator import main

if __name__ == "__main__":
    sys.exit(main())
