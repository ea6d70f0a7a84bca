#!/usr/bin/env python3
"""Train a learned controller with PPO; DD-PPO when launched by torchrun.

    python scripts/train_policy.py --kind quality|navigation|novelty|av_navigator [--updates N] [--out DIR]
    torchrun --standalone --nproc_per_node 2 scripts/train_policy.py --kind quality ...

Same as ``python -m m2h_ros.training.ppo_cli`` (the flags); ``m2h_ros.training.ppo`` has the loop, the rewards and the outputs.
A run directory that holds a resume state of the same settings is continued exactly.
"""

import sys

from m2h_ros.training.ppo_cli import main

if __name__ == "__main__":
    sys.exit(main())
