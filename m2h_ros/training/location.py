"""The target-location auxiliary task (``PPOConfig.location_coef``): the GRU learns where the target is.

Kickstarting from the approach teacher did not take for pi^Q (docs/design/policies.md): one step's binaural
cue says little about which way the target lies, and PPO's sparse return does not teach the policy to
gather that over steps and turns. An auxiliary loss does it directly (as in UNREAL, Jaderberg et al.
2017, and the depth / localisation heads of navigation agents): a linear head on the GRU's output
predicts the target's position relative to the robot, forward and left in metres, from what the
policy sees, and its Huber loss trains the GRU and the encoders beside PPO's. The head exists only
in training (the shipped policy has no such layer, and acting is unchanged); the labels come from the
episode (the target's node), which only training reads.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import torch
import torch.nn.functional as F
from torch import nn

from m2h_ros.core.world.episodes import Episode
from m2h_ros.core.world.navgrid import heading_angle

HUBER_METRES = 1.0  # the loss is quadratic within a metre of the target's position, linear beyond


def target_offsets(episodes: Sequence[Episode], nodes: np.ndarray, headings: np.ndarray) -> np.ndarray:
    """(slots, 2) float32: each slot's target position relative to the robot at (node, heading) in its
    episode, as (forward, left) metres in the robot's frame."""
    offsets = np.empty((len(episodes), 2), np.float32)
    for slot, episode in enumerate(episodes):
        positions = episode.scene().grid.positions
        dx, dy = positions[episode.target_node] - positions[int(nodes[slot])]
        yaw = heading_angle(int(headings[slot]))
        offsets[slot] = (dx * np.cos(yaw) + dy * np.sin(yaw), -dx * np.sin(yaw) + dy * np.cos(yaw))
    return offsets


def location_head(hidden: int) -> nn.Linear:
    """The head: GRU output (..., hidden) -> the target's (forward, left) offset in metres."""
    return nn.Linear(hidden, 2)


def location_loss(predicted: torch.Tensor, offsets: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """(Huber loss, mean distance in metres between predicted and true positions), over all steps."""
    loss = F.smooth_l1_loss(predicted, offsets, beta=HUBER_METRES)
    with torch.no_grad():
        error = (predicted - offsets).norm(dim=-1).mean()
    return loss, error
