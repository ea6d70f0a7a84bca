"""Separator pretraining data, recorded from the simulator (numpy only; cached on disk).

A dataset is a set of *sequences*: one episode played by a seeded random policy for ``steps``
observations (step 0 = the start pose, then ``steps - 1`` random MoveForward / TurnLeft / TurnRight
actions). Per observation it keeps the binaural mixture's log(1 + |STFT|) (2 x 512 x 32, what the
environment publishes) and the magnitude of the target alone as heard (``info["target_binaural"]``,
2 x 512 x 32); per sequence the magnitude of the target's dry monaural clip (512 x 32: each source
plays one clip for the whole episode), the target class index and the number of sources (the
mixture is the sum of the renders divided by it, so the target's share of the mixture is
target_binaural / n_sources). Keeping whole sequences lets the acoustic-memory refiner f^R train on
the estimates of consecutive steps.

RIR simulation (seconds per source node) dominates the cost of new geometry, clips cost nothing, so
each episode's geometry can be replayed with ``sound_variants`` independently drawn clip sets (same
categories and sound split; variant 0 is the episode as generated).

Cache: ``data_dir()/separator_data/v<VERSION>/<key>/`` with ``.npy`` arrays (float16 spectrograms)
and ``meta.json``; the key hashes the config, the sound library's fingerprint and the version.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import os
import shutil
import tempfile
import time
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from tqdm import tqdm

from m2h_ros.core.audio.stft import stft
from m2h_ros.core.sounds.library import SoundLibrary
from m2h_ros.core.world.acoustics import AcousticsConfig
from m2h_ros.core.world.env import BatchEnv, EnvConfig
from m2h_ros.core.world.episodes import (
    MOVE_FORWARD,
    TURN_LEFT,
    TURN_RIGHT,
    Episode,
    EpisodeConfig,
    episodes_for,
    scene_at,
)
from m2h_ros.core.world.rir_bank import RirBank
from m2h_ros.errors import CacheError, ConfigError
from m2h_ros.paths import data_dir

DATA_VERSION = 1
# The random policy: forward half of the time so the agent travels, turns otherwise (never Stop,
# which would end a far-target episode early).
POLICY_ACTIONS = np.array([MOVE_FORWARD, TURN_LEFT, TURN_RIGHT])
POLICY_PROBS = np.array([0.5, 0.25, 0.25])
_ARRAYS = ("mixture_logmag", "target_binaural", "target_monaural", "class_index", "n_sources", "mixture_power")


def _audio_only() -> EnvConfig:
    return EnvConfig(camera=False)


@dataclass(frozen=True)
class SeparatorDataConfig:
    """Which episodes are recorded and how; every field is part of the cache key."""

    episodes: tuple[EpisodeConfig, ...]
    sound_variants: int = 1  # clip sets per episode geometry (variant 0 = the episode's own clips)
    steps: int = 11  # observations per sequence: the start pose + steps - 1 random actions
    seed: int = 0  # random policy and variant clips
    env: EnvConfig = field(default_factory=_audio_only)

    def __post_init__(self) -> None:
        if not self.episodes or not all(isinstance(e, EpisodeConfig) for e in self.episodes):
            raise ConfigError(f"SeparatorDataConfig.episodes must be a non-empty tuple of EpisodeConfig, "
                              f"got {self.episodes!r}")
        object.__setattr__(self, "episodes", tuple(self.episodes))
        for name, low in (("sound_variants", 1), ("steps", 1), ("seed", 0)):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, int) or value < low:
                raise ConfigError(f"SeparatorDataConfig.{name} must be an int >= {low}, got {value!r}")
        too_short = [e for e in self.episodes if e.steps < self.steps - 1]
        if too_short:
            raise ConfigError(f"SeparatorDataConfig.steps={self.steps} needs episodes of at least "
                              f"{self.steps - 1} steps; {too_short[0]} has {too_short[0].steps}")
        if not isinstance(self.env, EnvConfig) or self.env.camera:
            raise ConfigError("SeparatorDataConfig.env must be an EnvConfig with camera=False")

    @classmethod
    def _near_and_far(cls, split: str, sound_split: str, near: int, far: int, *, seed: int,
                      sound_variants: int) -> SeparatorDataConfig:
        return cls(episodes=tuple(
            EpisodeConfig(task=task, scene_split=split, sound_split=sound_split, count=count, seed=seed)
            for task, count in (("near_target", near), ("far_target", far))),
            sound_variants=sound_variants, steps=11, seed=seed)

    @classmethod
    def training(cls, *, seed: int = 0) -> SeparatorDataConfig:
        """Default pretraining set: train scenes, heard sounds, near and far starts (see docs)."""
        return cls._near_and_far("train", "heard", 96, 48, seed=seed, sound_variants=4)

    @classmethod
    def validation(cls, *, seed: int = 0) -> SeparatorDataConfig:
        """Default validation set: val scenes, unheard sounds."""
        return cls._near_and_far("val", "unheard", 36, 12, seed=seed, sound_variants=1)

    @property
    def n_sequences(self) -> int:
        return sum(e.count for e in self.episodes) * self.sound_variants

    def to_dict(self) -> dict:
        return dataclasses.asdict(self)

    def key(self, library: SoundLibrary) -> str:
        text = json.dumps({"config": self.to_dict(), "library": library.fingerprint, "version": DATA_VERSION},
                          sort_keys=True)
        return hashlib.sha256(text.encode()).hexdigest()[:16]

    def path(self, library: SoundLibrary) -> Path:
        return data_dir() / "separator_data" / f"v{DATA_VERSION}" / self.key(library)


@dataclass(frozen=True)
class SeparatorDataset:
    """Recorded sequences: S sequences of T observations (arrays may be memory-mapped)."""

    mixture_logmag: np.ndarray  # (S, T, 2, F, T') float16, log(1 + |mixture STFT|)
    target_binaural: np.ndarray  # (S, T, 2, F, T') float16, |STFT| of the target alone as heard
    target_monaural: np.ndarray  # (S, F, T') float16, |STFT| of the target's dry clip
    class_index: np.ndarray  # (S,) int64, index into TARGET_CATEGORIES
    n_sources: np.ndarray  # (S,) int64
    mixture_power: np.ndarray  # (S, T) float32, mean power of the mixture waveform
    path: Path | None = None
    meta: dict = field(default_factory=dict)  # meta.json: config, library, build times

    @property
    def n_sequences(self) -> int:
        return self.mixture_logmag.shape[0]

    @property
    def steps(self) -> int:
        return self.mixture_logmag.shape[1]

    @property
    def n_samples(self) -> int:
        return self.n_sequences * self.steps

    def nbytes(self) -> int:
        return sum(getattr(self, name).nbytes for name in _ARRAYS)


def variant_episodes(episodes: list[Episode], library: SoundLibrary, *, variants: int, seed: int) -> list[Episode]:
    """Each episode followed by ``variants - 1`` copies with fresh clips of the same categories."""
    out = []
    for index, episode in enumerate(episodes):
        out.append(episode)
        for variant in range(1, variants):
            rng = np.random.default_rng([seed, index, variant])
            clips = tuple(library.sample(rng, category=c, split=episode.sound_split)[1]
                          for c in episode.source_categories)
            out.append(dataclasses.replace(episode, episode_id=f"{episode.episode_id}/v{variant}",
                                           source_clips=clips, seed=int(rng.integers(2**31))))
    return out


def policy_actions(seed: int, sequence: int, n_actions: int) -> np.ndarray:
    """The random policy's actions for one sequence (independent of batching)."""
    rng = np.random.default_rng([seed, sequence])
    return rng.choice(POLICY_ACTIONS, size=n_actions, p=POLICY_PROBS)


def _simulate_source(split: str, preset: str, index: int, node: int, acoustics: AcousticsConfig,
                     cache_dir: Path | None) -> None:
    """Worker: compute one source node's RIRs into the bank cache (rirs() builds missing nodes)."""
    RirBank(scene_at(split, preset, index), acoustics, cache_dir=cache_dir, progress=False).rirs([node], [0], [0])


def prebuild_rirs(episodes: list[Episode], acoustics: AcousticsConfig, *, cache_dir: Path | None = None,
                  workers: int = 2, progress: bool = True) -> int:
    """Simulate the source nodes the episodes need that are not cached yet, in parallel processes.

    The environment would compute them lazily in its own process; this does it on ``workers`` cores
    first. Returns the number of source nodes simulated.
    """
    needed = sorted({(e.scene_split, e.scene_preset, e.scene_index, node) for e in episodes for node in e.source_nodes})
    missing = [job for job in needed
               if not RirBank(scene_at(*job[:3]), acoustics, cache_dir=cache_dir, progress=False).path(job[3]).exists()]
    if not missing:
        return 0
    bar = tqdm(total=len(missing), desc="RIR source nodes", unit="src", disable=not progress)
    if workers > 1 and len(missing) > 1:
        with ProcessPoolExecutor(max_workers=workers) as pool:
            for future in [pool.submit(_simulate_source, *job, acoustics, cache_dir) for job in missing]:
                future.result()
                bar.update()
    else:
        for job in missing:
            _simulate_source(*job, acoustics, cache_dir)
            bar.update()
    bar.close()
    return len(missing)


def record(config: SeparatorDataConfig, library: SoundLibrary, out: Path, *, n_envs: int = 16,
           rir_cache_dir: Path | None = None, progress: bool = True) -> None:
    """Play every sequence in the environment and write the arrays into the folder ``out``."""
    episodes = [e for c in config.episodes for e in episodes_for(c, library)]
    sequences = variant_episodes(episodes, library, variants=config.sound_variants, seed=config.seed)
    s, t, stft_config = len(sequences), config.steps, config.env.stft
    spec_shape = (2, stft_config.n_freq, stft_config.n_frames)
    out.mkdir(parents=True, exist_ok=True)

    def create(name: str, shape: tuple[int, ...], dtype) -> np.ndarray:
        return np.lib.format.open_memmap(out / f"{name}.npy", mode="w+", dtype=dtype, shape=shape)

    arrays = {"mixture_logmag": create("mixture_logmag", (s, t, *spec_shape), np.float16),
              "target_binaural": create("target_binaural", (s, t, *spec_shape), np.float16),
              "target_monaural": create("target_monaural", (s, *spec_shape[1:]), np.float16),
              "class_index": create("class_index", (s,), np.int64),
              "n_sources": create("n_sources", (s,), np.int64),
              "mixture_power": create("mixture_power", (s, t), np.float32)}
    arrays["n_sources"][:] = [len(e.source_nodes) for e in sequences]
    n_envs = min(n_envs, s)
    env = BatchEnv(sequences, library, n_envs=n_envs, config=config.env, rir_cache_dir=rir_cache_dir,
                   autoreset=False)
    try:
        with tqdm(total=s * t, desc="recording", unit="obs", disable=not progress) as bar:
            for first in range(0, s, n_envs):
                rows = np.arange(first, min(first + n_envs, s))
                # A short last batch pads its free slots with its first sequence and drops them.
                slots = np.concatenate([rows, np.full(n_envs - len(rows), rows[0])])
                actions = np.stack([policy_actions(config.seed, int(i), t - 1) for i in slots])
                obs, info = env.reset(episodes=[sequences[i] for i in slots])
                keep = slice(0, len(rows))
                arrays["class_index"][rows] = obs["target_class"][keep]
                arrays["target_monaural"][rows] = np.abs(stft(info["target_monaural"][keep], config=stft_config))
                for step in range(t):
                    if step:
                        obs, _, _, _, info = env.step(actions[:, step - 1])
                    arrays["mixture_logmag"][rows, step] = obs["spectrogram"][keep]
                    arrays["target_binaural"][rows, step] = np.abs(stft(info["target_binaural"][keep],
                                                                        config=stft_config))
                    arrays["mixture_power"][rows, step] = np.mean(np.square(obs["audio"][keep]), axis=(1, 2))
                    bar.update(len(rows))
    finally:
        env.close()
    for array in arrays.values():
        array.flush()
    del arrays


def load_dataset(path: Path, *, mmap: bool = True) -> SeparatorDataset:
    """Open a recorded dataset folder; CacheError if it is incomplete or inconsistent."""
    try:
        meta = json.loads((path / "meta.json").read_text())
        arrays = {name: np.load(path / f"{name}.npy", mmap_mode="r" if mmap else None) for name in _ARRAYS}
    except (OSError, ValueError, KeyError) as exc:
        raise CacheError(f"separator dataset at {path} is incomplete or corrupt ({exc}): delete it to rebuild") from exc
    s, t = arrays["mixture_logmag"].shape[:2]
    if meta.get("version") != DATA_VERSION or meta.get("n_sequences") != s or meta.get("steps") != t \
            or any(arrays[name].shape[0] != s for name in _ARRAYS):
        raise CacheError(f"separator dataset at {path} does not match its meta.json: delete it to rebuild")
    return SeparatorDataset(**arrays, path=path, meta=meta)


def separator_dataset(config: SeparatorDataConfig, library: SoundLibrary, *, n_envs: int = 16,
                      rir_workers: int = 2, rir_cache_dir: Path | None = None, progress: bool = True,
                      mmap: bool = True) -> SeparatorDataset:
    """The dataset of ``config``: from the cache, or simulated now (RIRs first) and cached atomically."""
    final = config.path(library)
    if (final / "meta.json").exists():
        return load_dataset(final, mmap=mmap)
    started = time.perf_counter()
    episodes = [e for c in config.episodes for e in episodes_for(c, library)]
    simulated = prebuild_rirs(episodes, config.env.acoustics, cache_dir=rir_cache_dir, workers=rir_workers,
                              progress=progress)
    rir_seconds = time.perf_counter() - started
    final.parent.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=f".{final.name}.", dir=final.parent))
    try:
        record(config, library, tmp, n_envs=n_envs, rir_cache_dir=rir_cache_dir, progress=progress)
        meta = {"version": DATA_VERSION, "config": config.to_dict(), "library": library.fingerprint,
                "n_sequences": config.n_sequences, "steps": config.steps,
                "rir_nodes_simulated": simulated, "rir_seconds": round(rir_seconds, 1),
                "record_seconds": round(time.perf_counter() - started - rir_seconds, 1)}
        (tmp / "meta.json").write_text(json.dumps(meta, indent=1))
        if final.exists():  # a half-written folder of an interrupted run (no meta.json)
            shutil.rmtree(final)
        os.replace(tmp, final)
    finally:
        if tmp.exists():
            shutil.rmtree(tmp)
    return load_dataset(final, mmap=mmap)
