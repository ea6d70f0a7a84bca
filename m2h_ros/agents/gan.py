"""Gan et al. (paper Sec. 5, after "Look, Listen, and Act", ICRA 2020): hear where the target is, map
the room from depth, plan a path there, and stop when the Stop predictor hears the robot is at it.

* **Where**: the supervised sound locator (``m2h_ros.models.locator``) predicts from each step's
  binaural mixture the target's offset from the robot; turned into map coordinates with the robot's
  odometry, the predictions since the last plan are averaged into the goal. The goal is re-predicted
  every ``replan_every`` steps (20, as the issue's description of the baseline), and at once when
  the robot reaches a goal at which the Stop predictor does not fire.
* **Map**: an occupancy map on the 1 m cells the robot moves between, built from the depth camera:
  every depth pixel back-projected (pinhole, the simulator's camera) to a point; points between 0.1
  and 1.9 m above the floor are obstacles. Obstacle points in a cell's interior block the cell, points
  on the line between two cells block the move across it (walls; door gaps stay open), and a
  MoveForward that left the robot where it was blocks that move. Unseen cells count as free.
* **Plan**: breadth-first search over the map's cells to the goal's cell (or, if it is blocked or cut
  off, to the reachable cell nearest to it); the first move of the path becomes TurnLeft / TurnRight
  until the robot faces it, then MoveForward.
* **Stop**: when the Stop predictor's probability has exceeded ``stop_threshold`` on
  ``stop_patience`` consecutive steps (one step alone fires too often away from the target: 1-6%
  of the validation split's observations, docs/design/baselines.md). Near-target episodes (where Stop is
  a no-op) never stop on purpose; the planner simply keeps going.

It reads the mixture, the odometry and the depth image, never the separator's outputs.
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass, field
from pathlib import Path
from typing import ClassVar

import numpy as np

from m2h_ros.agents.base import ControllerObservation, EpisodeStart
from m2h_ros.agents.baselines import TaskAware
from m2h_ros.core.sounds.library import TARGET_CATEGORIES
from m2h_ros.core.world.camera import CameraConfig, pixel_slopes
from m2h_ros.core.world.episodes import MOVE_FORWARD, STOP, TURN_LEFT, TURN_RIGHT
from m2h_ros.core.world.navgrid import HEADING_STEPS, N_HEADINGS, heading_index
from m2h_ros.errors import ConfigError
from m2h_ros.models.locator import DEFAULT_LOCATOR_CHECKPOINT, load_locator, map_position

OBSTACLE_Z = (0.1, 1.9)  # metres above the floor: what the robot would hit
WALL_BAND = 0.12  # metres either side of a cell boundary that count as "on the line between cells"
MIN_POINTS = 3  # obstacle points that block a cell or a move
PIXEL_STRIDE = 4  # every 4th row and column of the depth image


@dataclass
class OccupancyMap:
    """Blocked cells and blocked moves (cell, heading) on the 1 m grid, in map coordinates."""

    camera: CameraConfig = field(default_factory=CameraConfig)
    blocked_cells: set[tuple[int, int]] = field(default_factory=set)
    blocked_moves: set[tuple[int, int, int]] = field(default_factory=set)

    def __post_init__(self) -> None:
        right, up = pixel_slopes(self.camera)
        self._right, self._up = right[None, ::PIXEL_STRIDE], up[::PIXEL_STRIDE, None]

    def block_move(self, cell: tuple[int, int], heading: int) -> None:
        self.blocked_moves.add((*cell, heading))
        dx, dy = HEADING_STEPS[heading]
        self.blocked_moves.add((cell[0] + int(dx), cell[1] + int(dy), (heading + 2) % N_HEADINGS))

    def add_depth(self, depth: np.ndarray, pose: np.ndarray) -> None:
        """Obstacles seen in one depth image (H, W, metres along the optical axis) from ``pose``."""
        d = np.asarray(depth, np.float64)[::PIXEL_STRIDE, ::PIXEL_STRIDE]
        z = self.camera.eye_height + self._up * d
        seen = (d < self.camera.max_depth - 1e-3) & (z > OBSTACLE_Z[0]) & (z < OBSTACLE_Z[1])
        if not seen.any():
            return
        x, y, yaw = (float(v) for v in pose)
        forward, right = np.array([np.cos(yaw), np.sin(yaw)]), np.array([np.sin(yaw), -np.cos(yaw)])
        depth_seen, lateral = d[seen], (self._right * d)[seen]
        points = np.array([x, y]) + depth_seen[:, None] * forward + lateral[:, None] * right
        cells = np.floor(points).astype(np.int64)
        frac = points - cells
        near_x = np.minimum(frac[:, 0], 1 - frac[:, 0]) < WALL_BAND
        near_y = np.minimum(frac[:, 1], 1 - frac[:, 1]) < WALL_BAND
        interior = ~near_x & ~near_y
        for cell, count in zip(*np.unique(cells[interior], axis=0, return_counts=True)):
            if count >= MIN_POINTS:
                self.blocked_cells.add((int(cell[0]), int(cell[1])))
        # On a vertical line x = k (not at a corner): the move between cells k-1 and k along x.
        for axis, on_line in ((0, near_x & ~near_y), (1, near_y & ~near_x)):
            line = np.round(points[on_line, axis]).astype(np.int64)
            other = cells[on_line, 1 - axis]
            for (k, o), count in zip(*np.unique(np.stack([line, other], axis=1), axis=0, return_counts=True)):
                if count >= MIN_POINTS:
                    below = (int(k) - 1, int(o)) if axis == 0 else (int(o), int(k) - 1)
                    self.block_move(below, 0 if axis == 0 else 1)  # heading +x or +y across the line

    def free_moves(self, cell: tuple[int, int]):
        for heading, (dx, dy) in enumerate(HEADING_STEPS):
            nxt = (cell[0] + int(dx), cell[1] + int(dy))
            if (*cell, heading) not in self.blocked_moves and nxt not in self.blocked_cells:
                yield heading, nxt

    def first_move(self, start: tuple[int, int], goal: tuple[int, int], *, margin: int = 12) -> int | None:
        """Heading of the first move of a shortest path from ``start`` to ``goal`` (or to the reachable
        cell nearest the goal), searched within ``margin`` cells around both; None: already there."""
        lo = np.minimum(start, goal) - margin
        hi = np.maximum(start, goal) + margin
        first: dict[tuple[int, int], int | None] = {start: None}
        queue = deque([start])
        best, best_distance = start, np.hypot(start[0] - goal[0], start[1] - goal[1])
        while queue:
            cell = queue.popleft()
            if cell == goal:
                best = cell
                break
            for heading, nxt in self.free_moves(cell):
                if nxt in first or not (lo[0] <= nxt[0] <= hi[0] and lo[1] <= nxt[1] <= hi[1]):
                    continue
                first[nxt] = heading if first[cell] is None else first[cell]
                distance = np.hypot(nxt[0] - goal[0], nxt[1] - goal[1])
                if distance < best_distance:
                    best, best_distance = nxt, distance
                queue.append(nxt)
        return first[best]


def move_toward(heading: int, wanted: int) -> int:
    if wanted == heading:
        return MOVE_FORWARD
    return TURN_LEFT if wanted == (heading + 1) % N_HEADINGS else TURN_RIGHT


class GanEtAl(TaskAware):
    name = "gan_et_al"
    summary = "sound locator + Stop predictor, depth occupancy map, BFS planner (paper Sec. 5, Gan et al. 2020)"
    uses_camera: ClassVar[bool] = True  # depth

    def __init__(self, n_slots: int, *, seed: int = 0, checkpoint: str = "", replan_every: int = 20,
                 stop_threshold: float = 0.7, stop_patience: int = 2, camera: CameraConfig = CameraConfig()) -> None:
        super().__init__(n_slots, seed=seed)
        if isinstance(replan_every, bool) or not isinstance(replan_every, int) or replan_every < 1:
            raise ConfigError(f"replan_every={replan_every!r} must be a positive int")
        if not 0.0 < float(stop_threshold) < 1.0:
            raise ConfigError(f"stop_threshold={stop_threshold!r} must be in (0, 1)")
        if isinstance(stop_patience, bool) or not isinstance(stop_patience, int) or stop_patience < 1:
            raise ConfigError(f"stop_patience={stop_patience!r} must be a positive int")
        self.locator = load_locator(checkpoint or DEFAULT_LOCATOR_CHECKPOINT)
        self.replan_every, self.camera = replan_every, camera
        self.stop_threshold, self.stop_patience = float(stop_threshold), stop_patience
        self.confident = np.zeros(self.n_slots, np.int64)  # consecutive steps the Stop head fired
        self.maps = [OccupancyMap(camera) for _ in range(self.n_slots)]
        self.goals: list[np.ndarray | None] = [None] * self.n_slots
        self.heard: list[list[np.ndarray]] = [[] for _ in range(self.n_slots)]  # goal estimates since the plan
        self.last: list[tuple[tuple[int, int], int] | None] = [None] * self.n_slots  # pose of the last act
        self.moved_forward = np.zeros(self.n_slots, bool)  # whether the last action was MoveForward
        self.target_class = np.zeros(self.n_slots, np.int64)

    def model_files(self) -> list[Path]:
        return [self.locator.path]

    def reset(self, slot: int, start: EpisodeStart) -> None:
        super().reset(slot, start)
        if start.target_class not in TARGET_CATEGORIES:
            raise ConfigError(f"{self.name}: unknown target class {start.target_class!r}")
        self.target_class[slot] = TARGET_CATEGORIES.index(start.target_class)
        self.maps[slot] = OccupancyMap(self.camera)
        self.goals[slot], self.heard[slot], self.last[slot] = None, [], None
        self.moved_forward[slot] = False
        self.confident[slot] = 0

    def _act(self, obs: ControllerObservation) -> np.ndarray:
        if obs.depth is None:
            raise ConfigError(f"{self.name} needs the depth camera: use EnvConfig(camera=True)")
        offset, on_target = self.locator.predict(obs.audio, self.target_class)
        poses = obs.pose.astype(np.float64)
        heard = map_position(offset, poses)  # where each slot's step says the target is
        confident = on_target > self.stop_threshold
        self.confident = np.where(confident, self.confident + 1, 0)
        actions = np.empty(self.n_slots, np.int64)
        for slot in range(self.n_slots):
            pose = poses[slot]
            cell, heading = (int(np.floor(pose[0])), int(np.floor(pose[1]))), heading_index(pose[2])
            occupancy = self.maps[slot]
            if self.last[slot] == (cell, heading) and self.moved_forward[slot]:
                occupancy.block_move(cell, heading)  # the MoveForward went nowhere
            occupancy.add_depth(obs.depth[slot], pose)
            self.heard[slot].append(heard[slot])
            if self.far[slot] and self.confident[slot] >= self.stop_patience:
                actions[slot] = STOP
            else:
                actions[slot] = self._navigate(slot, int(obs.step[slot]), cell, heading)
            self.last[slot] = (cell, heading)
            self.moved_forward[slot] = actions[slot] == MOVE_FORWARD
        return actions

    def _navigate(self, slot: int, step: int, cell: tuple[int, int], heading: int) -> int:
        goal = self.goals[slot]
        arrived = goal is not None and cell == (int(np.floor(goal[0])), int(np.floor(goal[1])))
        if goal is None or step % self.replan_every == 0 or arrived:
            goal = self.goals[slot] = np.mean(self.heard[slot], axis=0)
            self.heard[slot] = []
        goal_cell = (int(np.floor(goal[0])), int(np.floor(goal[1])))
        wanted = self.maps[slot].first_move(cell, goal_cell)
        if wanted is None:  # on the goal's cell and not stopping: look around for a better estimate
            return TURN_LEFT
        return move_toward(heading, wanted)
