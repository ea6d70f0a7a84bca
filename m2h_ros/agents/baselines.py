"""Controllers that need no training: the paper's training-free baselines (Move2Hear, Sec. 5 and
supplementary Sec. 10).

The original code (github.com/SAGNIKMJR/move2hear-active-AV-separation) holds no baseline
implementation, so what it does fix is taken from its environment: the actions a policy may take
are MoveForward, TurnLeft and TurnRight in both tasks (``TASK.POSSIBLE_ACTIONS``), and its action 0
is a no-op "pause" that never ends an episode. Here action 0 is Stop, a no-op in near-target that
ends a far-target episode (the AV-Navigator task), so a controller that wants to stay where it is in
far-target turns left and right in place instead (:func:`hold_in_place`).

All of them see only :class:`~m2h_ros.agents.base.ControllerObservation`: odometry, audio, separator
outputs. The start pose is the pose of an episode's step-0 observation. docs/design/baselines.md has the
choices made and the measurements behind them.
"""

from __future__ import annotations

import numpy as np

from m2h_ros.agents.base import Controller, ControllerObservation, EpisodeStart
from m2h_ros.core.audio.doa import interaural_level_difference
from m2h_ros.core.audio.stft import stft
from m2h_ros.core.world.episodes import MOVE_FORWARD, STOP, TURN_LEFT, TURN_RIGHT, EpisodeConfig
from m2h_ros.errors import ConfigError

# The original's POSSIBLE_ACTIONS: what the random baselines draw from.
MOTIONS = np.array([MOVE_FORWARD, TURN_LEFT, TURN_RIGHT], np.int64)
STEP_LENGTH = 1.0  # m per MoveForward (the navigation grid's lattice): the robot's own stride
MOVED = 1e-3  # m of odometry change that counts as having moved


def hold_in_place(count: np.ndarray, far: np.ndarray) -> np.ndarray:
    """Actions that keep the robot on its node: Stop (a no-op) in near-target; in far-target, where
    Stop would end the episode, TurnLeft then TurnRight, so after an even number of them the pose
    is the one the hold began at. ``count``: hold actions each slot has taken so far."""
    return np.where(far, np.where(np.asarray(count) % 2 == 0, TURN_LEFT, TURN_RIGHT), STOP).astype(np.int64)


class TaskAware(Controller):
    """Keeps each slot's task (whether Stop would end its episode). No baseline reads the separator."""

    uses_separator = False

    def __init__(self, n_slots: int, *, seed: int = 0) -> None:
        super().__init__(n_slots, seed=seed)
        self.far = np.zeros(self.n_slots, bool)

    def reset(self, slot: int, start: EpisodeStart) -> None:
        super().reset(slot, start)
        self.far[slot] = start.task == "far_target"


class StandInPlace(TaskAware):
    """Stand In-Place (paper Sec. 5): the passive reference, the separator hears the whole episode
    from the start pose. Stop in near-target (a no-op; the original's "pause"); in far-target it turns
    left and right in place (:func:`hold_in_place`), which stays on the start node and ends at the start
    heading after the even 100 steps (Stop would end the episode after its first observation)."""

    name = "stand_in_place"
    summary = "never leaves the start node (paper Sec. 5: the passive reference)"

    def _act(self, obs: ControllerObservation) -> np.ndarray:
        return hold_in_place(obs.step, self.far)


class RotateInPlace(TaskAware):
    """Rotate In-Place (paper Sec. 5): stays on the start node and keeps turning, so the separator
    hears the scene from all four headings in turn. Always TurnLeft (the direction is arbitrary; the
    original code does not say); after a multiple of 4 steps (20 and 100) it faces the start heading."""

    name = "rotate_in_place"
    summary = "turns left at every step on the start node (paper Sec. 5)"

    def _act(self, obs: ControllerObservation) -> np.ndarray:
        return np.full(obs.n_slots, TURN_LEFT, np.int64)


class RandomActions(TaskAware):
    """Random (paper Sec. 5): a uniform draw from MoveForward / TurnLeft / TurnRight at every step (the
    original's possible actions; never Stop), from the slot's generator (seeded by the controller's
    and the episode's seeds, so an episode's actions do not depend on its slot)."""

    name = "random"
    summary = "uniformly random MoveForward / TurnLeft / TurnRight (paper Sec. 5)"

    def _act(self, obs: ControllerObservation) -> np.ndarray:
        return np.array([MOTIONS[self.rngs[slot].integers(len(MOTIONS))] for slot in range(obs.n_slots)])


class MoveForward(TaskAware):
    """Move Forward (paper Sec. 5): MoveForward unless blocked, then TurnRight. Blocked is what a
    robot with a bumper but no map knows: its odometry did not change over its last MoveForward. So
    it spends one step against each obstacle; it reads no camera, and runs with the camera off."""

    name = "move_forward"
    summary = "forward until a move fails (odometry unchanged), then turn right (paper Sec. 5)"

    def __init__(self, n_slots: int, *, seed: int = 0) -> None:
        super().__init__(n_slots, seed=seed)
        self.last_action = np.full(self.n_slots, -1, np.int64)
        self.last_xy = np.zeros((self.n_slots, 2))

    def reset(self, slot: int, start: EpisodeStart) -> None:
        super().reset(slot, start)
        self.last_action[slot] = -1

    def _act(self, obs: ControllerObservation) -> np.ndarray:
        xy = np.asarray(obs.pose[:, :2], np.float64)
        blocked = (self.last_action == MOVE_FORWARD) & (np.linalg.norm(xy - self.last_xy, axis=1) < MOVED)
        actions = np.where(blocked, TURN_RIGHT, MOVE_FORWARD).astype(np.int64)
        self.last_action[:], self.last_xy[:] = actions, xy
        return actions


# Near-target episodes start within this geodesic (so also straight-line) distance of the target.
DEFAULT_PROXIMITY_RADIUS = EpisodeConfig().near_radius


class ProximityPrior(TaskAware):
    """Proximity Prior (paper Sec. 5): random actions as :class:`RandomActions`, but a MoveForward that
    would end more than ``radius`` metres (straight line) from the start pose becomes a random turn.
    "Would end" is predicted from the odometry pose and the robot's 1 m stride, so the robot never
    leaves the circle. Default radius: the near-target task's start radius (3 m), the circle that holds
    every place the target can be; the paper's own value could not be checked (not in the code)."""

    name = "proximity_prior"
    summary = "random actions that never leave a circle around the start (paper Sec. 5)"

    def __init__(self, n_slots: int, *, seed: int = 0, radius: float = DEFAULT_PROXIMITY_RADIUS) -> None:
        super().__init__(n_slots, seed=seed)
        if isinstance(radius, bool) or not isinstance(radius, (int, float)) or not np.isfinite(radius) \
                or radius <= 0:
            raise ConfigError(f"ProximityPrior radius={radius!r} must be a positive number of metres")
        self.radius = float(radius)
        self.start_xy = np.zeros((self.n_slots, 2))

    def _act(self, obs: ControllerObservation) -> np.ndarray:
        pose = np.asarray(obs.pose, np.float64)
        first = np.asarray(obs.step) == 0
        self.start_xy[first] = pose[first, :2]
        ahead = pose[:, :2] + STEP_LENGTH * np.column_stack([np.cos(pose[:, 2]), np.sin(pose[:, 2])])
        outside = np.linalg.norm(ahead - self.start_xy, axis=1) > self.radius + 1e-6
        actions = np.empty(obs.n_slots, np.int64)
        for slot in range(obs.n_slots):
            rng = self.rngs[slot]
            action = MOTIONS[rng.integers(len(MOTIONS))]
            if action == MOVE_FORWARD and outside[slot]:
                action = (TURN_LEFT, TURN_RIGHT)[rng.integers(2)]
            actions[slot] = action
        return actions


# DoA phases of a slot.
FIRST_LISTEN, SECOND_LISTEN, TURN, HOLD = 0, 1, 2, 3


class DirectionOfArrival(TaskAware):
    """DoA (paper Sec. 5, supplementary Sec. 10): turn to face the target's direction of arrival, move
    one step toward it, then stay (:func:`hold_in_place`).

    The direction comes from the binaural mixture's interaural level difference above 1.5 kHz
    (:func:`~m2h_ros.core.audio.doa.interaural_level_difference`): the near-target task's target is
    the nearest source, so it dominates the mixture's ILD. Not the ITD: in these rooms the early
    reflections outweigh the direct sound, and GCC-PHAT's ITD hardly follows the bearing even for the
    target alone (``scripts/bench/doa_cues.py``). Not f^B's separated binaural either: its ILD
    follows the bearing less well than the mixture's (same bench).

    An interaural cue says left/right but not front/back, so it listens twice: at the start heading
    (ILD_0 ~ sin(azimuth)) and after one TurnLeft (ILD_1 ~ sin(azimuth - 90 deg) = -cos(azimuth)).
    The larger of |ILD_0| and |ILD_1| names the axis, its sign the side: left (ILD_0 > 0: face the
    start heading + 90 deg, where it already is), right (2 turns), ahead (ILD_1 < 0: 1 turn right)
    or behind (1 turn left). Then one MoveForward. Every episode spends its first step on the turn.
    """

    name = "doa"
    summary = "face the target's interaural (ILD) direction, one step toward it, stay (paper supp. Sec. 10)"

    def __init__(self, n_slots: int, *, seed: int = 0) -> None:
        super().__init__(n_slots, seed=seed)
        self.phase = np.full(self.n_slots, FIRST_LISTEN, np.int64)
        self.first_ild = np.zeros(self.n_slots)
        self.pending = np.zeros(self.n_slots, np.int64)  # turns still to make: > 0 left, < 0 right
        self.hold_since = np.zeros(self.n_slots, np.int64)

    def reset(self, slot: int, start: EpisodeStart) -> None:
        super().reset(slot, start)
        self.phase[slot], self.first_ild[slot], self.pending[slot], self.hold_since[slot] = FIRST_LISTEN, 0, 0, 0

    @staticmethod
    def heading_offset(first_ild: float, second_ild: float) -> int:
        """Quarter turns (counter-clockwise) from the start heading to the source's direction."""
        if abs(first_ild) >= abs(second_ild):
            return 1 if first_ild > 0 else -1
        return 0 if second_ild < 0 else 2

    def _act(self, obs: ControllerObservation) -> np.ndarray:
        step = np.asarray(obs.step, np.int64)
        listening = np.flatnonzero(self.phase <= SECOND_LISTEN)
        ild = np.zeros(obs.n_slots)
        if len(listening):
            ild[listening] = interaural_level_difference(np.abs(stft(np.asarray(obs.audio[listening], np.float32))))
        actions = hold_in_place(step - self.hold_since, self.far)
        for slot in range(obs.n_slots):
            if self.phase[slot] == FIRST_LISTEN:
                self.first_ild[slot], self.phase[slot] = ild[slot], SECOND_LISTEN
                actions[slot] = TURN_LEFT
                continue
            if self.phase[slot] == SECOND_LISTEN:
                # It faces the start heading + 1 now.
                self.pending[slot] = self.heading_offset(self.first_ild[slot], ild[slot]) - 1
                self.phase[slot] = TURN
            if self.phase[slot] == TURN:
                if self.pending[slot]:
                    actions[slot] = TURN_LEFT if self.pending[slot] > 0 else TURN_RIGHT
                    self.pending[slot] -= np.sign(self.pending[slot])
                else:
                    actions[slot] = MOVE_FORWARD
                    self.phase[slot], self.hold_since[slot] = HOLD, step[slot] + 1
        return actions
