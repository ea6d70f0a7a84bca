"""A privileged diagnostic controller: what an agent that knows where the target is gains by going there.

:class:`ApproachOracle` reads the target's node from the episode list it is built with (ground truth
no real controller gets, hence not in ``agents.registry``: neither the controller node nor
``scripts/evaluate.py`` can run it). It walks one shortest path to that node, turning where the path
turns, and then holds there as Stand In-Place holds (Stop, a no-op, in near-target), or, with
``hold="turn"`` (``approach_oracle_turning``), turns left on the node every step: the only way pi^Q,
which has no Stop, can stay on it, and the teacher's way (``training.teacher``). Its final-step
SI-SDR against Stand In-Place's on the same episodes bounds what learning to approach the target can
give with this separator and simulator (``scripts/experiments/approach_oracle.py``).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from m2h_ros.agents.base import ControllerObservation, EpisodeStart
from m2h_ros.agents.baselines import TaskAware, hold_in_place
from m2h_ros.core.world.episodes import TURN_LEFT, Episode
from m2h_ros.core.world.navgrid import NavGrid, heading_index
from m2h_ros.errors import ConfigError
from m2h_ros.training.teacher import approach_action


class ApproachOracle(TaskAware):
    """Walks a shortest path to the target's node (known from ``episodes``), then holds there
    (``hold``: "stand" as Stand In-Place, "turn" turning left on the node)."""

    name = "approach_oracle"
    summary = "privileged diagnostic: a shortest path to the target's node, then holds (not a baseline)"
    HOLDS = {"stand": "approach_oracle", "turn": "approach_oracle_turning"}  # hold -> controller name

    def __init__(self, n_slots: int, *, episodes: Sequence[Episode], hold: str = "stand", seed: int = 0) -> None:
        super().__init__(n_slots, seed=seed)
        if hold not in self.HOLDS:
            raise ConfigError(f"{self.name}: hold={hold!r} must be one of {sorted(self.HOLDS)}")
        self.name, self._turns = self.HOLDS[hold], hold == "turn"
        self._episodes = {e.episode_id: e for e in episodes}
        self._grid: list[NavGrid | None] = [None] * self.n_slots
        self._goal = np.zeros(self.n_slots, np.int64)
        self._holds = np.zeros(self.n_slots, np.int64)

    def reset(self, slot: int, start: EpisodeStart) -> None:
        super().reset(slot, start)
        episode = self._episodes.get(start.episode_id)
        if episode is None:
            raise ConfigError(f"{self.name}: episode {start.episode_id!r} is not in the list it was given")
        self._grid[slot], self._goal[slot], self._holds[slot] = episode.scene().grid, episode.target_node, 0

    def _act(self, obs: ControllerObservation) -> np.ndarray:
        actions = np.empty(self.n_slots, np.int64)
        for slot in range(self.n_slots):
            grid = self._grid[slot]
            node = grid.nearest_node(obs.pose[slot, :2].astype(np.float64))
            action = approach_action(grid, node, heading_index(float(obs.pose[slot, 2])), int(self._goal[slot]))
            if action is None:
                action = TURN_LEFT if self._turns else int(hold_in_place(self._holds[slot], self.far[slot]))
                self._holds[slot] += 1
            actions[slot] = action
        return actions
