"""Plays a list of episodes one at a time, as the simulator node does: one-slot ``BatchEnv``, an
explicit episode per reset, the terminal observation returned like any other.

``EpisodePlayer.start(i)`` begins episode i and returns its first observation; ``step(action)``
returns the next one and whether the episode ended there (truncated after max_steps actions, or Stop
in far-target). Observations and ground truth are the environment's, slot 0 of its batches.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from m2h_ros.core.sounds.library import SoundLibrary
from m2h_ros.core.world.env import BatchEnv, EnvConfig
from m2h_ros.core.world.episodes import Episode
from m2h_ros.errors import M2HError


@dataclass(frozen=True)
class PlayerStep:
    obs: dict  # batched (leading dim 1) environment observation
    info: dict  # batched ground truth (target clip and render, delay, geodesic distance, ...)
    done: bool  # the episode ended at this observation


class EpisodePlayer:
    def __init__(self, episodes: Sequence[Episode], library: SoundLibrary, *, config: EnvConfig = EnvConfig(),
                 rir_cache_dir: Path | None = None) -> None:
        self.episodes = list(episodes)
        self.env = BatchEnv(self.episodes, library, n_envs=1, config=config, rir_cache_dir=rir_cache_dir,
                            autoreset=False)
        self.episode: Episode | None = None
        self.done = True

    @property
    def scene(self):
        return self.env.scene_of(0)

    def start(self, index: int) -> PlayerStep:
        obs, info = self.env.reset(episodes=[index])
        self.episode, self.done = self.env.current_episodes[0], False
        return PlayerStep(obs, info, False)

    def step(self, action: int, *, hold: bool = False) -> PlayerStep:
        if self.done:
            raise M2HError("the episode has ended: start() the next one")
        obs, _, terminated, truncated, info = self.env.step(np.array([action], np.int64),
                                                            hold=np.array([hold]))
        self.done = bool(terminated[0] or truncated[0])
        return PlayerStep(obs, info, self.done)

    def close(self) -> None:
        self.env.close()
