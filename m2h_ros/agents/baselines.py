"""Controllers that need no training (the paper's training-free baselines, Sec. 5 and supp. Sec. 10)."""

from __future__ import annotations

import numpy as np

from m2h_ros.agents.base import Controller, ControllerObservation
from m2h_ros.core.world.episodes import STOP


class StandInPlace(Controller):
    """Stand In-Place: never moves; the passive separator refines its estimate over the episode
    (the paper's main passive reference). Near-target only makes sense: Stop is a no-op there, and in
    far-target it would end the episode at once, so it turns left and right in place instead."""

    name = "stand_in_place"
    summary = "never moves (paper Sec. 5: the passive reference)"

    def _act(self, obs: ControllerObservation) -> np.ndarray:
        return np.full(obs.n_slots, STOP, np.int64)
