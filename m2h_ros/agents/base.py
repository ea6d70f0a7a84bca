"""The controller interface: one action per step from what the robot can observe.

Every controller (baselines, learned policies) implements :class:`Controller`, batched over slots so
in-process evaluation and training run many episodes at once; :class:`SingleEpisode` is the view the
controller node uses (one slot). A controller is told an episode's public facts at its start
(:class:`EpisodeStart`) and gets a :class:`ControllerObservation` per step. Neither type has a field
for the ground truth (the target's clip, its position, the geodesic distance): a controller cannot
cheat, and a test checks the field lists.

Stochastic controllers draw from one generator per slot, seeded from the controller's seed and the
episode's own seed at reset: an episode gets the same actions whichever slot, batch size or process
(in-process or through the ROS graph) plays it.
"""

from __future__ import annotations

import dataclasses
from abc import ABC, abstractmethod
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import ClassVar

import numpy as np

from m2h_ros.core.world.env import N_ACTIONS
from m2h_ros.core.world.episodes import TASKS, Episode
from m2h_ros.errors import ConfigError

_RNG_SALT = 0x636F6E74  # separates a controller's stream from the episode's other uses of its seed


@dataclass(frozen=True)
class EpisodeStart:
    """What a controller may know about an episode when it starts (EpisodeInfo carries the same)."""

    episode_id: str
    task: str  # "near_target" | "far_target"
    target_class: str  # "speech" | "music"
    max_steps: int  # actions in the episode (observations: max_steps + 1)
    seed: int  # the episode's seed (seeds stochastic controllers)

    def __post_init__(self) -> None:
        if self.task not in TASKS:
            raise ConfigError(f"EpisodeStart.task={self.task!r} must be one of {TASKS}")
        if self.max_steps < 1:
            raise ConfigError(f"EpisodeStart.max_steps={self.max_steps!r} must be >= 1")

    @classmethod
    def of(cls, episode: Episode) -> EpisodeStart:
        return cls(episode.episode_id, episode.task, episode.target_category, episode.max_steps,
                   episode.seed)


@dataclass(frozen=True)
class ControllerObservation:
    """One step's observation of B slots (leading dim B everywhere; images None without a camera).

    Magnitudes are linear |STFT| in the (F, T) = (512, 32) layout of :mod:`m2h_ros.core.audio.stft`;
    the separator's outputs are None for a controller that does not use them (``uses_separator``).
    """

    step: np.ndarray  # (B,) int64, 0 = the observation after the episode's reset
    pose: np.ndarray  # (B, 3) float32 odometry: x, y (m), yaw (rad, counter-clockwise from +x)
    audio: np.ndarray  # (B, 2, N) float32 binaural mixture as heard (left, right)
    separated_binaural: np.ndarray | None  # (B, 2, F, T) float32 f^B's estimate of the target as heard
    monaural: np.ndarray | None  # (B, F, T) float32 f^M's monaural estimate
    refined: np.ndarray | None  # (B, F, T) float32 f^R's refined estimate (acoustic memory)
    rgb: np.ndarray | None = None  # (B, H, W, 3) uint8
    depth: np.ndarray | None = None  # (B, H, W) float32 metres

    def __post_init__(self) -> None:
        b = len(self.step)
        for f in dataclasses.fields(self):
            value = getattr(self, f.name)
            if value is not None and len(value) != b:
                raise ConfigError(f"ControllerObservation.{f.name} has {len(value)} rows, step has {b}")

    @property
    def n_slots(self) -> int:
        return len(self.step)

    def rows(self, index: np.ndarray | slice) -> ControllerObservation:
        """The observation of some slots (a view where numpy gives one)."""
        return ControllerObservation(**{f.name: None if getattr(self, f.name) is None
                                        else getattr(self, f.name)[index] for f in dataclasses.fields(self)})

    @classmethod
    def stack(cls, observations: Sequence[ControllerObservation]) -> ControllerObservation:
        values = {}
        for f in dataclasses.fields(cls):
            parts = [getattr(o, f.name) for o in observations]
            values[f.name] = None if any(p is None for p in parts) else np.concatenate(parts)
        return cls(**values)


class Controller(ABC):
    """A batched controller: ``reset(slot, start)`` when a slot starts an episode, ``act(obs)`` for
    all slots at once. Subclasses keep per-slot state in arrays indexed by slot."""

    name: ClassVar[str]
    #: One line, with the source in the paper: shown by ``scripts/evaluate.py --list``.
    summary: ClassVar[str]
    #: Whether the controller needs camera images (the sim may then skip rendering them).
    uses_camera: ClassVar[bool] = False
    #: Whether it reads the separator's outputs. If not, it gets None for them, and the controller
    #: node neither subscribes to them nor waits for the separator: its command leaves while the
    #: separator still works on the step (off the lockstep's critical path).
    uses_separator: ClassVar[bool] = True

    def __init__(self, n_slots: int, *, seed: int = 0) -> None:
        if isinstance(n_slots, bool) or not isinstance(n_slots, (int, np.integer)) or n_slots < 1:
            raise ConfigError(f"n_slots={n_slots!r} must be a positive int")
        if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or seed < 0:
            raise ConfigError(f"seed={seed!r} must be a non-negative int")
        self.n_slots, self.seed = int(n_slots), int(seed)
        self.starts: list[EpisodeStart | None] = [None] * self.n_slots
        self.rngs: list[np.random.Generator | None] = [None] * self.n_slots

    def reset(self, slot: int, start: EpisodeStart) -> None:
        """Slot ``slot`` starts the episode ``start``; subclasses extend this to clear their state."""
        if not 0 <= slot < self.n_slots:
            raise ConfigError(f"slot {slot} is not in [0, {self.n_slots})")
        self.starts[slot] = start
        self.rngs[slot] = np.random.default_rng([self.seed, start.seed, _RNG_SALT])

    def model_files(self) -> list[Path]:
        """The trained models this controller has loaded (none for the training-free ones): what a
        results table must name besides its command, since the shipped files change."""
        return []

    def act(self, obs: ControllerObservation) -> np.ndarray:
        """(B,) int64 actions (STOP, MOVE_FORWARD, TURN_LEFT, TURN_RIGHT) for the B slots."""
        if obs.n_slots != self.n_slots:
            raise ConfigError(f"{self.name}: observation of {obs.n_slots} slots for {self.n_slots}")
        missing = [slot for slot, start in enumerate(self.starts) if start is None]
        if missing:
            raise ConfigError(f"{self.name}: slots {missing} act before reset()")
        actions = np.asarray(self._act(obs), np.int64)
        if actions.shape != (self.n_slots,) or actions.min() < 0 or actions.max() >= N_ACTIONS:
            raise ConfigError(f"{self.name} returned invalid actions {actions!r}")
        return actions

    @abstractmethod
    def _act(self, obs: ControllerObservation) -> np.ndarray:
        """The policy itself: (B,) actions for a validated observation of all slots."""


class SingleEpisode:
    """One-slot view of a controller, as the controller node uses it."""

    def __init__(self, controller: Controller) -> None:
        if controller.n_slots != 1:
            raise ConfigError(f"SingleEpisode needs a one-slot controller, got {controller.n_slots} slots")
        self.controller = controller

    @property
    def name(self) -> str:
        return self.controller.name

    def reset(self, start: EpisodeStart) -> None:
        self.controller.reset(0, start)

    def act(self, obs: ControllerObservation) -> int:
        return int(self.controller.act(obs)[0])
