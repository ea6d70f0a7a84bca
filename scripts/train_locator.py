#!/usr/bin/env python3
"""Train the Gan et al. baseline's sound locator (target position + Stop from binaural audio).

    python scripts/train_locator.py --samples 30000 --epochs 12 --out m2h_ros/models/default/locator.pt

Same as ``python -m m2h_ros.training.train_locator``; see that module for the data and losses.
"""

import sys

from m2h_ros.training.train_locator import main

if __name__ == "__main__":
    sys.exit(main())
