"""The approach teacher: privileged action labels that kickstart PPO (``PPOConfig.teacher_coef``).

Kickstarting (Schmitt et al. 2018, "Kickstarting Deep Reinforcement Learning"): besides PPO's loss,
the student minimises the cross-entropy from a teacher's action distribution at the states the
student itself visits (DAgger's on-policy states, so it learns to recover from its own mistakes),
with a weight that decays to zero, so the trained policy is PPO's on the kind's own reward.

The teacher knows the target's node (ground truth, which only training reads; the policy still sees
only what a controller sees). It follows one shortest path there (:func:`approach_action`); on the
target's node it says Stop where the policy has Stop (pi^N: success), else TurnLeft or TurnRight with
equal probability (pi^Q has no Stop: turning is how it stays on the node). Approaching is what
pays here: a walk to the target's node gains +1.25 dB near-target and +6.7 dB far-target over Stand
In-Place with the shipped separator (``scripts/experiments/approach_oracle.py``), while PPO on the
sparse quality reward alone learns to stay.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from m2h_ros.core.world.episodes import MOVE_FORWARD, STOP, TURN_LEFT, TURN_RIGHT, Episode
from m2h_ros.core.world.navgrid import N_HEADINGS, NavGrid
from m2h_ros.errors import ConfigError


def approach_action(grid: NavGrid, node: int, heading: int, goal: int) -> int | None:
    """The action that follows a shortest path from (node, heading) to ``goal``; None at the goal.

    MoveForward when it shortens the geodesic; otherwise the turn towards the nearest heading that does
    (left first on a tie: turning round takes two turns either way)."""
    if node == goal:
        return None
    here = grid.geodesic[node, goal]
    if grid.geodesic[grid.forward[node, heading], goal] < here:
        return MOVE_FORWARD
    for turns, action in ((1, TURN_LEFT), (-1, TURN_RIGHT), (2, TURN_LEFT)):
        h = (heading + turns) % N_HEADINGS
        if grid.geodesic[grid.forward[node, h], goal] < here:
            return action
    raise ConfigError(f"node {goal} cannot be reached from node {node}")


def teacher_probabilities(episodes: Sequence[Episode], nodes: np.ndarray, headings: np.ndarray,
                          env_actions: np.ndarray) -> np.ndarray:
    """(slots, outputs) float32: the teacher's distribution over the policy's outputs (``env_actions``,
    the environment action of each output) for each slot at (node, heading) in its episode."""
    column = {int(action): i for i, action in enumerate(env_actions)}
    if not {MOVE_FORWARD, TURN_LEFT, TURN_RIGHT} <= column.keys():
        raise ConfigError(f"the approach teacher needs MoveForward and both turns among the actions, got {env_actions}")
    probabilities = np.zeros((len(episodes), len(env_actions)), np.float32)
    for slot, episode in enumerate(episodes):
        action = approach_action(episode.scene().grid, int(nodes[slot]), int(headings[slot]), episode.target_node)
        if action is not None:
            probabilities[slot, column[action]] = 1.0
        elif STOP in column:
            probabilities[slot, column[STOP]] = 1.0
        else:
            probabilities[slot, [column[TURN_LEFT], column[TURN_RIGHT]]] = 0.5
    return probabilities
