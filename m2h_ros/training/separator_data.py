"""Separator training data drawn on the fly from the simulator (a torch IterableDataset).

Nothing is recorded: batch ``i`` of a :class:`StreamConfig` is a pure function of ``(seed, i)``, so
any number of DataLoader worker processes (each renders every ``workers``-th batch in its own
``BatchEnv``) and any resume point give the same batches in the same order.

One *sequence* of a batch:

1. an episode drawn afresh (``episodes.draw_episode``): a template of ``config.episodes`` (task,
   splits, placement rules) picked uniformly, then a scene of its split uniformly, then the source
   placement (minimum inter-source distance), a start pose, categories and clips;
2. a random walk of 0..``max_walk`` actions from that start (the random policy below, applied to the
   navigation grid without rendering), so observations cover the poses an agent visits, not only
   start poses;
3. ``steps`` observations rendered by ``BatchEnv`` from there (the policy acting between them), with
   the augmentation (training only): each source's clip scaled by a gain uniform in +-``gain_db`` dB
   (target and distractors drawn independently) and, in a ``noise_fraction`` of the sequences,
   microphone noise of a level drawn from ``noise_levels``: white noise per ear of std level x the
   RMS of the clean mixture, the environment's ``EnvConfig.mic_noise`` model; and, with ``eq_db`` > 0, a
   random smooth **spectral colouring** of each source (see :func:`colouring_gains`): a sound of the
   same class recorded elsewhere differs from the heard clips mostly in its spectral envelope, which a
   separator otherwise learns clip by clip; and, with ``speed_min`` < 1, a **slow-down** of each
   sequence (see :func:`slow_down`): every signal of it played at a speed uniform in [speed_min, 1],
   new pitches and tempi from the same clips.

Per observation a batch holds |STFT| of the (augmented) binaural mixture, what the separator takes,
and |STFT| of the target's share of it (its render x gain / number of sources: the mixture is the
sum of the renders divided by that number, so this is what a ratio mask can reach); per sequence
|STFT| of the dry target clip x its gain and the class index. Tensors are in the sliced layout.
The sound library and the RIR banks come in through ``fork`` (workers share their pages).
"""

from __future__ import annotations

import dataclasses
import zlib
from collections.abc import Iterator
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass, field
from pathlib import Path
from typing import NamedTuple

import numpy as np
import torch
from scipy.signal import resample_poly
from torch.utils.data import IterableDataset, get_worker_info
from tqdm import tqdm

from m2h_ros.core.audio.stft import stft, to_slices
from m2h_ros.core.sounds.library import SoundLibrary
from m2h_ros.core.world.acoustics import AcousticsConfig
from m2h_ros.core.world.env import BatchEnv, EnvConfig
from m2h_ros.core.world.episodes import (
    MOVE_FORWARD,
    TURN_LEFT,
    TURN_RIGHT,
    Episode,
    EpisodeConfig,
    draw_episode,
    scene_at,
)
from m2h_ros.core.world.navgrid import NavGrid, turn_left, turn_right
from m2h_ros.core.world.rir_bank import RirBank
from m2h_ros.core.world.scene import Scene
from m2h_ros.core.world.worlds import worlds_of
from m2h_ros.config import check_int_fields
from m2h_ros.errors import ConfigError

# The random policy: forward half of the time so the agent travels, turns otherwise (never Stop,
# which would end a far-target episode early).
POLICY_ACTIONS = np.array([MOVE_FORWARD, TURN_LEFT, TURN_RIGHT])
POLICY_PROBS = np.array([0.5, 0.25, 0.25])
# Microphone noise levels of the training augmentation (std relative to the clean mixture's RMS,
# SNR 26 / 20 / 14 dB): the levels to run the noise-robustness experiment at.
MIC_NOISE_LEVELS = (0.05, 0.1, 0.2)
# Slow-down: speeds are SPEED_STEPS-ths (a rational resampling ratio); SPEED_MIN_LIMIT bounds how far.
SPEED_STEPS = 64
SPEED_MIN_LIMIT = 0.5
_STREAM_SALT = 0x736570  # separates the stream's draws from other uses of the same seed
_SUBSET_SALT = 0x6E6F6465


def _audio_only() -> EnvConfig:
    return EnvConfig(camera=False)


def _near_and_far(split: str, sound_split: str) -> tuple[EpisodeConfig, ...]:
    return tuple(EpisodeConfig(task=task, scene_split=split, sound_split=sound_split)
                 for task in ("near_target", "far_target"))


@dataclass(frozen=True)
class StreamConfig:
    """What a stream draws; every field changes the batches."""

    episodes: tuple[EpisodeConfig, ...]  # templates (``count`` and ``seed`` are not used)
    scenes: int | None = None  # only the first this many scenes of each template's split (None: all)
    source_nodes: int | None = None  # sources only on this many nodes per scene (see source_subset)
    batch_size: int = 16  # sequences per batch
    steps: int = 1  # observations per sequence
    max_walk: int = 19  # random actions before the first observation: uniform in 0..max_walk
    gain_db: float = 0.0  # per-source gain uniform in [-gain_db, +gain_db] dB
    noise_levels: tuple[float, ...] = ()  # microphone noise levels, one drawn per noisy sequence
    noise_fraction: float = 0.0  # share of sequences with microphone noise
    eq_db: float = 0.0  # per-source spectral colouring of at most this many dB (0: none)
    speed_min: float = 1.0  # per-sequence playback speed uniform in [speed_min, 1] (1: none)
    seed: int = 0
    env: EnvConfig = field(default_factory=_audio_only)

    def __post_init__(self) -> None:
        if not self.episodes or not all(isinstance(e, EpisodeConfig) for e in self.episodes):
            raise ConfigError(f"StreamConfig.episodes must be a non-empty tuple of EpisodeConfig, got {self.episodes!r}")
        object.__setattr__(self, "episodes", tuple(self.episodes))
        object.__setattr__(self, "noise_levels", tuple(float(v) for v in self.noise_levels))
        for name in ("scenes", "source_nodes"):
            value = getattr(self, name)
            if value is not None and (isinstance(value, bool) or not isinstance(value, int) or value < 1):
                raise ConfigError(f"StreamConfig.{name} must be None or an int >= 1, got {value!r}")
        check_int_fields(self, (("batch_size", 2), ("steps", 1), ("max_walk", 0), ("seed", 0)))
        if len({e.n_distractors for e in self.episodes}) != 1:
            raise ConfigError("StreamConfig.episodes must all have the same n_distractors (one BatchEnv holds them)")
        too_short = [e for e in self.episodes if e.steps < self.steps - 1]
        if too_short:
            raise ConfigError(f"StreamConfig.steps={self.steps} needs episodes of at least {self.steps - 1} "
                              f"steps; {too_short[0]} has {too_short[0].steps}")
        for name in ("gain_db", "eq_db"):
            value = getattr(self, name)
            if not (np.isfinite(value) and 0 <= value <= 20):
                raise ConfigError(f"StreamConfig.{name} must be in [0, 20], got {value!r}")
        if not (np.isfinite(self.speed_min) and SPEED_MIN_LIMIT <= self.speed_min <= 1):
            raise ConfigError(f"StreamConfig.speed_min must be in [{SPEED_MIN_LIMIT}, 1], got {self.speed_min!r}")
        if not 0 <= self.noise_fraction <= 1 or (self.noise_fraction > 0 and not self.noise_levels):
            raise ConfigError(f"StreamConfig.noise_fraction must be in [0, 1] (> 0 needs noise_levels), "
                              f"got {self.noise_fraction!r} with levels {self.noise_levels}")
        if not all(np.isfinite(v) and v > 0 for v in self.noise_levels):
            raise ConfigError(f"StreamConfig.noise_levels must be positive, got {self.noise_levels}")
        if not isinstance(self.env, EnvConfig) or self.env.camera or self.env.mic_noise:
            raise ConfigError("StreamConfig.env must be an EnvConfig with camera=False and mic_noise=0 "
                              "(the stream adds its own noise, after the gains)")

    @classmethod
    def training(cls, *, seed: int = 0, batch_size: int = 16, steps: int = 1, scenes: int | None = None,
                 source_nodes: int | None = None, eq_db: float = 0.0, speed_min: float = 1.0) -> StreamConfig:
        """Train scenes, heard sounds, near and far starts, gain +-3 dB, noise in half the sequences."""
        return cls(episodes=_near_and_far("train", "heard"), scenes=scenes, source_nodes=source_nodes,
                   batch_size=batch_size, steps=steps, gain_db=3.0, noise_levels=MIC_NOISE_LEVELS,
                   noise_fraction=0.5, eq_db=eq_db, speed_min=speed_min, seed=seed)

    @classmethod
    def validation(cls, *, seed: int = 0, batch_size: int = 16, steps: int = 8,
                   source_nodes: int | None = None) -> StreamConfig:
        """Val scenes, unheard sounds, no augmentation (the test conditions)."""
        return cls(episodes=_near_and_far("val", "unheard"), source_nodes=source_nodes, batch_size=batch_size,
                   steps=steps, seed=seed)

    def to_dict(self) -> dict:
        return dataclasses.asdict(self)


def stream_scenes(config: StreamConfig, template: EpisodeConfig) -> list[Scene]:
    """The scenes a stream draws from for one template: its split's, or the first ``config.scenes``."""
    scenes = worlds_of(template.scene_split, preset=template.scene_preset)
    if config.scenes is not None and config.scenes > len(scenes):
        raise ConfigError(f"StreamConfig.scenes={config.scenes}, but split {template.scene_split!r} has "
                          f"{len(scenes)} scenes")
    return scenes[: config.scenes]


def source_subset(scene: Scene, count: int | None) -> np.ndarray | None:
    """The nodes a stream may place sources on in ``scene``: ``count`` of them, the same for every
    stream and seed (seeded by the scene id), so one set of RIR source nodes serves them all; None: any."""
    if count is None or count >= scene.grid.n_nodes:
        return None
    rng = np.random.default_rng([_SUBSET_SALT, zlib.crc32(scene.scene_id.encode())])
    return np.sort(rng.permutation(scene.grid.n_nodes)[:count])


class SeparatorBatch(NamedTuple):
    """One batch in the sliced layout (S' = frequency slices): B sequences of T observations."""

    index: int  # position in the stream
    mixture: torch.Tensor  # (B, T, 2S', H, W) |STFT| of the binaural mixture
    share: torch.Tensor  # (B, T, 2S', H, W) |STFT| of the target's share of the mixture
    monaural: torch.Tensor  # (B, S', H, W) |STFT| of the dry target clip (x its gain)
    class_index: torch.Tensor  # (B,) int64, index into TARGET_CATEGORIES
    power: torch.Tensor  # (B, T) mean power of the mixture waveform

    def observations(self) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor]:
        """The batch as B*T single observations: (mixture, share, monaural, class)."""
        b, t = self.mixture.shape[:2]
        return (self.mixture.flatten(0, 1), self.share.flatten(0, 1),
                self.monaural.repeat_interleave(t, dim=0), self.class_index.repeat_interleave(t))


# Spectral colouring: a sum of EQ_COMPONENTS cosines over log frequency from EQ_LOW_HZ to Nyquist, so a
# curve has at most a few broad peaks and dips (an envelope, not comb filtering).
EQ_COMPONENTS = 3
EQ_LOW_HZ = 60.0


def colouring_gains(coefficients: np.ndarray, phases: np.ndarray, n_samples: int, sample_rate: int) -> np.ndarray:
    """Linear gains per rfft bin of ``n_samples``-long signals, one curve per row of ``coefficients``
    (dB amplitudes, (N, EQ_COMPONENTS)) and ``phases`` (radians, same shape): gain_dB(u) = sum_k
    c_k cos(pi k u + phase_k), u the bin's log frequency mapped to [0, 1] from EQ_LOW_HZ to Nyquist
    (bins below EQ_LOW_HZ take u = 0). |gain_dB| <= sum_k |c_k|."""
    freqs = np.fft.rfftfreq(n_samples, 1.0 / sample_rate)
    nyquist = sample_rate / 2.0
    u = np.log(np.clip(freqs, EQ_LOW_HZ, nyquist) / EQ_LOW_HZ) / np.log(nyquist / EQ_LOW_HZ)
    k = np.arange(1, coefficients.shape[1] + 1)
    curves_db = np.einsum("nk,nkf->nf", coefficients,
                          np.cos(np.pi * k[None, :, None] * u[None, None, :] + phases[:, :, None]))
    return (10.0 ** (curves_db / 20.0)).astype(np.float32)


def _colour(waveform: np.ndarray, gains: np.ndarray) -> np.ndarray:
    """``waveform`` (B, ..., samples) filtered by its row's gains (B, bins), in the frequency domain
    over the whole clip (the curves are smooth, so the filter is short and circular wrap negligible)."""
    shape = (len(gains),) + (1,) * (waveform.ndim - 2) + (gains.shape[1],)
    spectrum = np.fft.rfft(waveform, axis=-1) * gains.reshape(shape)
    return np.fft.irfft(spectrum, n=waveform.shape[-1], axis=-1).astype(np.float32)


def slow_down(waveform: np.ndarray, numerator: int) -> np.ndarray:
    """``waveform`` (..., samples) played at speed ``numerator / SPEED_STEPS`` <= 1, same length:
    y(t) = x(speed t), so every frequency is scaled by the speed and the first ``speed`` of the
    signal fills it. Applied to a render, that is the render of the slowed clip in a room scaled by
    1 / speed (all delays and decay times longer): a world the simulator could have made, which is
    why only slowing down (it needs no samples past the end of the 1 s render) is offered."""
    if numerator >= SPEED_STEPS:
        return waveform
    n = waveform.shape[-1]
    # A few input samples past what the output needs, so the polyphase filter's end transient falls
    # after the last kept sample.
    used = min(n, -(-n * numerator // SPEED_STEPS) + 64)
    out = resample_poly(waveform[..., :used], SPEED_STEPS, numerator, axis=-1)
    return np.ascontiguousarray(out[..., :n], dtype=np.float32)


def _slow_rows(waveform: np.ndarray, numerators: np.ndarray) -> np.ndarray:
    """Row ``b`` of ``waveform`` (B, ..., samples) slowed down by ``numerators[b]``."""
    return np.stack([slow_down(row, int(k)) for row, k in zip(waveform, numerators)])


def policy_actions(rng: np.random.Generator, n: int) -> np.ndarray:
    return rng.choice(POLICY_ACTIONS, size=n, p=POLICY_PROBS)


def walk(grid: NavGrid, node: int, heading: int, actions: np.ndarray) -> tuple[int, int]:
    """The pose after ``actions`` (the environment's motion rule, without rendering)."""
    for action in actions.tolist():
        if action == MOVE_FORWARD:
            node = int(grid.forward[node, heading])
        elif action == TURN_LEFT:
            heading = int(turn_left(heading))
        elif action == TURN_RIGHT:
            heading = int(turn_right(heading))
    return node, heading


@dataclass(frozen=True)
class _Plan:
    """The draws of one batch: episodes (starting at the walked pose), actions, gains, noise."""

    episodes: list[Episode]
    actions: np.ndarray  # (B, steps - 1)
    gains: np.ndarray  # (B, 2) linear: target, distractors
    noise: np.ndarray  # (B,) level, 0 = none
    noise_seeds: np.ndarray  # (B,)
    colouring: np.ndarray | None  # (B, 2, 2, EQ_COMPONENTS): target / distractors, dB amplitudes / phases
    speeds: np.ndarray | None  # (B,) slow-down numerators (speed x SPEED_STEPS), every signal of a sequence


class BatchSource:
    """Renders batches of a stream; holds one BatchEnv, built on first use (in the worker process)."""

    def __init__(self, config: StreamConfig, library: SoundLibrary, *, rir_cache_dir: Path | None = None) -> None:
        self.config, self.library, self.rir_cache_dir = config, library, rir_cache_dir
        self._candidates = [[source_subset(scene, config.source_nodes) for scene in stream_scenes(config, e)]
                            for e in config.episodes]
        self._env: BatchEnv | None = None

    def plan(self, index: int) -> _Plan:
        cfg = self.config
        rng = np.random.default_rng([cfg.seed, _STREAM_SALT, index])
        episodes = []
        for j in range(cfg.batch_size):
            which = int(rng.integers(len(cfg.episodes)))
            template = cfg.episodes[which]
            scene_index = int(rng.integers(len(self._candidates[which])))
            episode = draw_episode(rng, template, scene_index, self.library, episode_id=f"stream/{index}/{j}",
                                   source_candidates=self._candidates[which][scene_index])
            node, heading = walk(episode.scene().grid, episode.start_node, episode.start_heading,
                                 policy_actions(rng, int(rng.integers(cfg.max_walk + 1))))
            episodes.append(dataclasses.replace(episode, start_node=node, start_heading=heading))
        actions = policy_actions(rng, cfg.batch_size * (cfg.steps - 1)).reshape(cfg.batch_size, cfg.steps - 1)
        gains = 10.0 ** (rng.uniform(-cfg.gain_db, cfg.gain_db, (cfg.batch_size, 2)) / 20.0)
        noisy = rng.random(cfg.batch_size) < cfg.noise_fraction
        levels = np.asarray(cfg.noise_levels or (0.0,))[rng.integers(max(len(cfg.noise_levels), 1), size=cfg.batch_size)]
        noise_seeds = rng.integers(2**31, size=cfg.batch_size)
        colouring = None
        if cfg.eq_db > 0:  # drawn last, so streams without it keep their batches
            amplitudes = rng.uniform(-1.0, 1.0, (cfg.batch_size, 2, EQ_COMPONENTS))
            amplitudes *= cfg.eq_db / EQ_COMPONENTS
            phases = rng.uniform(0.0, 2.0 * np.pi, (cfg.batch_size, 2, EQ_COMPONENTS))
            colouring = np.stack([amplitudes, phases], axis=2)
        speeds = None
        if cfg.speed_min < 1:  # drawn after the colouring, for the same reason
            lowest = int(np.ceil(cfg.speed_min * SPEED_STEPS))
            speeds = rng.integers(lowest, SPEED_STEPS + 1, size=cfg.batch_size)
        return _Plan(episodes, actions, gains, np.where(noisy, levels, 0.0), noise_seeds, colouring, speeds)

    def batch(self, index: int) -> SeparatorBatch:
        cfg, plan = self.config, self.plan(index)
        stft_config = cfg.env.stft
        if self._env is None:
            # Single observations of fresh episodes never revisit a pose: no pose cache to fill.
            self._env = BatchEnv(plan.episodes, self.library, n_envs=cfg.batch_size, config=cfg.env,
                                 rir_cache_dir=self.rir_cache_dir, autoreset=False,
                                 pose_cache=32 if cfg.steps > 1 else 0)
        n_sources = np.array([len(e.source_nodes) for e in plan.episodes], np.float32)[:, None, None]
        target_gain, other_gain = (plan.gains[:, i, None, None].astype(np.float32) for i in range(2))
        noise_rngs = [np.random.default_rng(int(s)) for s in plan.noise_seeds]
        target_eq = other_eq = None
        if plan.colouring is not None:
            target_eq, other_eq = (colouring_gains(plan.colouring[:, i, 0], plan.colouring[:, i, 1],
                                                   stft_config.clip_samples, stft_config.sample_rate)
                                   for i in range(2))
        mixtures, shares, powers = [], [], []
        obs, info = self._env.reset(episodes=plan.episodes)
        for step in range(cfg.steps):
            if step:
                obs, _, _, _, info = self._env.step(plan.actions[:, step - 1])
            share = info["target_binaural"] / n_sources
            other = obs["audio"] - share
            if target_eq is not None:
                share, other = _colour(share, target_eq), _colour(other, other_eq)
            if plan.speeds is not None:
                share, other = _slow_rows(share, plan.speeds), _slow_rows(other, plan.speeds)
            mixture = target_gain * share + other_gain * other
            rms = np.sqrt(np.mean(np.square(mixture), axis=(1, 2)))
            for row in np.flatnonzero(plan.noise):
                noise = noise_rngs[row].standard_normal(mixture.shape[1:], dtype=np.float32)
                mixture[row] += np.float32(plan.noise[row] * rms[row]) * noise
            powers.append(np.mean(np.square(mixture), axis=(1, 2)))
            mixtures.append(np.abs(stft(mixture, config=stft_config)))
            shares.append(np.abs(stft(target_gain * share, config=stft_config)))
        dry = info["target_monaural"] if target_eq is None else _colour(info["target_monaural"], target_eq)
        if plan.speeds is not None:
            dry = _slow_rows(dry, plan.speeds)
        monaural = np.abs(stft(target_gain[:, 0] * dry, config=stft_config))[:, None]

        def sliced(array: np.ndarray) -> torch.Tensor:
            return torch.from_numpy(np.ascontiguousarray(to_slices(array, n_slices=stft_config.n_freq_slices)))

        return SeparatorBatch(index, sliced(np.stack(mixtures, axis=1)), sliced(np.stack(shares, axis=1)),
                              sliced(monaural), torch.from_numpy(obs["target_class"].astype(np.int64)),
                              torch.from_numpy(np.stack(powers, axis=1)))

    def close(self) -> None:
        if self._env is not None:
            self._env.close()
            self._env = None


class SeparatorStream(IterableDataset):
    """Batches ``start, start + 1, ..., stop - 1`` of a source, in order, over any number of workers
    (worker k renders the batches congruent to k; the DataLoader takes them round-robin). Use
    ``DataLoader(stream, batch_size=None, num_workers=w)``."""

    def __init__(self, source: BatchSource, start: int, stop: int) -> None:
        if not 0 <= start <= stop:
            raise ConfigError(f"SeparatorStream needs 0 <= start <= stop, got {start}, {stop}")
        self.source, self.start, self.stop = source, start, stop

    def __iter__(self) -> Iterator[SeparatorBatch]:
        worker = get_worker_info()
        first, step = (0, 1) if worker is None else (worker.id, worker.num_workers)
        if worker is not None:
            torch.set_num_threads(1)  # the worker's work is numpy/scipy; leave the cores to training
        try:
            for index in range(self.start + first, self.stop, step):
                yield self.source.batch(index)
        finally:
            if worker is not None:
                self.source.close()

    def __len__(self) -> int:
        return self.stop - self.start


def fixed_set(source: BatchSource, n_batches: int, *, progress: bool = True) -> list[SeparatorBatch]:
    """The first ``n_batches`` batches of a stream, rendered now (a fixed validation set)."""
    try:
        return [source.batch(i) for i in tqdm(range(n_batches), desc="validation set", unit="batch",
                                               disable=not progress)]
    finally:
        source.close()


def build_banks(config: StreamConfig, *, cache_dir: Path | None = None, workers: int = 2,
                progress: bool = True) -> int:
    """Simulate every missing RIR source node the stream can place a source on (all nodes of its
    scenes, or their ``source_subset``), on ``workers`` processes, so that no data worker stalls on
    RIR simulation. Returns the number of source nodes simulated."""
    jobs = []
    for template in {(e.scene_split, e.scene_preset): e for e in config.episodes}.values():
        for index, scene in enumerate(stream_scenes(config, template)):
            bank = RirBank(scene, config.env.acoustics, cache_dir=cache_dir, progress=False)
            subset = source_subset(scene, config.source_nodes)
            nodes = range(scene.grid.n_nodes) if subset is None else subset.tolist()
            jobs += [(template.scene_split, template.scene_preset, index, node) for node in nodes
                     if not bank.path(node).exists()]
    bar = tqdm(total=len(jobs), desc="RIR source nodes", unit="src", disable=not (progress and jobs))
    if workers > 1 and len(jobs) > 1:
        with ProcessPoolExecutor(max_workers=workers) as pool:
            for future in [pool.submit(_simulate_source, *job, config.env.acoustics, cache_dir) for job in jobs]:
                future.result()
                bar.update()
    else:
        for job in jobs:
            _simulate_source(*job, config.env.acoustics, cache_dir)
            bar.update()
    bar.close()
    return len(jobs)


def _simulate_source(split: str, preset: str, index: int, node: int, acoustics: AcousticsConfig,
                     cache_dir: Path | None) -> None:
    """Worker: compute one source node's RIRs into the bank cache (rirs() builds missing nodes)."""
    RirBank(scene_at(split, preset, index), acoustics, cache_dir=cache_dir, progress=False).rirs([node], [0], [0])
