"""The Move2Hear environment: many episode slots stepped together in one process, plus a Gymnasium
single-env wrapper over the same code.

``BatchEnv`` holds B slots; each plays episodes from a list in a fixed, seeded order and moves on to
its next episode when one ends (same-step auto-reset: the terminal observation goes to
``info["final_observation"]``). One step, for all slots at once:

* actions: MoveForward follows ``grid.forward[node, heading]``, TurnLeft (h + 1) % 4, TurnRight
  (h - 1) % 4, Stop ends a far-target episode and is a no-op in near-target;
* audio: every source's binaural RIR at the new pose (one RirBank per scene), convolved with its clip
  in the frequency domain (the clips' spectra are computed once per episode, since each source plays
  the same clip at every step), mixture = sum of the renders / number of sources (the original
  code's rule), plus microphone noise of std ``mic_noise`` x the mixture's RMS (a per-episode rng);
  the separators' input is log(1 + |STFT|) of that mixture;
* camera: RGB + depth from the per-scene view cache (optional: audio-only runs skip it);
* reward (AV Navigator, pi^N): +success_reward for Stop at the target (far-target), +-distance_reward
  per metre of geodesic distance gained/lost, -step_penalty per step. An episode is terminated by
  Stop (far-target) and truncated after ``max_steps`` actions (max_steps + 1 observations).

Observations (batched over slots): ``audio`` (B, 2, 16000) float32 mixture, ``spectrogram`` (B, 2, 512,
32) float32 log(1 + |STFT|) (only with ``EnvConfig(spectrogram=True)``), ``rgb`` (B, H, W, 3) uint8,
``depth`` (B, H, W, 1) float32 metres, ``pose`` (B, 3) float32 (x, y, heading angle in rad), ``node``,
``heading``, ``target_class`` (0 speech, 1 music), ``step`` (B,) int64. The ground truth the separators
are scored and trained on is in ``info``: the target's dry clip and the target alone as heard (its
binaural render, not divided by the number of sources, as in the original code's ground-truth
components), and ``target_delay`` (B,) float64, the samples after which the target's direct sound
reaches the head centre (straight-line distance, at least the acoustics' ``min_distance``, over the
speed of sound: where the RIRs put it, HRIR centre delay included), to delay-align the dry clip with
what the ears hear when scoring estimates in the mixture's phase.
"""

from __future__ import annotations

from collections import OrderedDict
from collections.abc import Sequence
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from functools import lru_cache
from pathlib import Path
from typing import Any

import gymnasium
import numpy as np
from gymnasium import spaces
from scipy import fft as sfft

from m2h_ros.allocator import keep_freed_blocks
from m2h_ros.core.audio.stft import DEFAULT_STFT, StftConfig
from m2h_ros.core.sounds.library import TARGET_CATEGORIES, SoundLibrary
from m2h_ros.core.world.acoustics import AcousticsConfig
from m2h_ros.core.world.camera import CameraConfig, CameraViews
from m2h_ros.core.world.episodes import MOVE_FORWARD, STOP, TURN_LEFT, TURN_RIGHT, Episode, scene_at
from m2h_ros.core.world.navgrid import N_HEADINGS, heading_angle
from m2h_ros.core.world.render import log_magnitude_into, render_pose, source_spectra
from m2h_ros.core.world.render_worker import RenderJob, RenderSetup, RenderWorkers
from m2h_ros.core.world.rir_bank import RirBank
from m2h_ros.core.world.rir_spectra import RirSpectra, StoredRirSpectra, convolution_length
from m2h_ros.core.world.scene import Scene
from m2h_ros.errors import ConfigError, EpisodeError, M2HError

N_ACTIONS = 4
_NOISE_SALT = 0x6D6963  # separates the microphone-noise stream from other uses of an episode seed

Observation = dict[str, np.ndarray]


@dataclass(frozen=True)
class EnvConfig:
    """Everything that changes what the environment returns (BatchEnv's threads and pose cache do not)."""

    mic_noise: float = 0.0  # noise std relative to the clean mixture's RMS
    camera: bool = True  # False: no rgb/depth (cheaper audio-only training)
    # True: the observations add the mixture's log-magnitude STFT ("spectrogram"), for agents of your own.
    # Off by default: the project's separators, controllers and training read the audio (the separator
    # takes its own STFT), and a fresh pose's render then skips one STFT.
    spectrogram: bool = False
    camera_config: CameraConfig = field(default_factory=CameraConfig)
    acoustics: AcousticsConfig = field(default_factory=AcousticsConfig)
    stft: StftConfig = DEFAULT_STFT
    success_reward: float = 10.0
    distance_reward: float = 0.25  # per metre of geodesic distance gained (lost: negative)
    step_penalty: float = 0.01
    seed: int = 0  # order in which the slots take the episodes
    shuffle: bool = True  # False: slot i plays episodes i, i + B, i + 2B, ... of the list

    def __post_init__(self) -> None:
        for name, kind in (("camera_config", CameraConfig), ("acoustics", AcousticsConfig),
                           ("stft", StftConfig)):
            if not isinstance(getattr(self, name), kind):
                raise ConfigError(f"EnvConfig.{name} must be a {kind.__name__}, "
                                  f"got {type(getattr(self, name)).__name__}")
        for name in ("mic_noise", "success_reward", "distance_reward", "step_penalty"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, (int, float)) or not np.isfinite(value):
                raise ConfigError(f"EnvConfig.{name}={value!r} must be a finite number")
        if self.mic_noise < 0:
            raise ConfigError(f"EnvConfig.mic_noise={self.mic_noise!r} must be >= 0")
        for name in ("camera", "spectrogram", "shuffle"):
            if not isinstance(getattr(self, name), bool):
                raise ConfigError(f"EnvConfig.{name}={getattr(self, name)!r} must be a bool")
        if isinstance(self.seed, bool) or not isinstance(self.seed, (int, np.integer)) or self.seed < 0:
            raise ConfigError(f"EnvConfig.seed={self.seed!r} must be a non-negative int")
        if self.acoustics.sample_rate != self.stft.sample_rate:
            raise ConfigError(f"EnvConfig: acoustics.sample_rate={self.acoustics.sample_rate} differs from "
                              f"stft.sample_rate={self.stft.sample_rate}")


@dataclass
class _SceneData:
    """Per-scene resources, created when a slot first plays an episode in that scene."""

    scene: Scene
    bank: RirBank
    views: CameraViews | None
    spectra: StoredRirSpectra | None   # with BatchEnv(stored_rir_spectra=True)


class _PoseCache:
    """One slot's renders (and, without microphone noise, spectrograms) of up to ``capacity``
    poses of its current episode, LRU, in arrays allocated once and reused by every later episode.

    One array per render made each episode's renders fresh heap memory, which glibc hands back to
    the system when a reset frees them all at once; the next episode then paid ~160 page faults
    per render (docs/design/simulator.md; ``allocator.keep_freed_blocks`` keeps such memory too).
    """

    def __init__(self, capacity: int, n_samples: int, spectrogram_shape: tuple[int, int], *,
                 spectrograms: bool, arrays: tuple[np.ndarray, np.ndarray | None] | None = None) -> None:
        self.capacity = capacity
        self._shapes = ((capacity, 4, n_samples), (capacity, 2, *spectrogram_shape) if spectrograms else None)
        self._entries: OrderedDict[tuple[int, int], int] = OrderedDict()
        # (capacity, 4, S): target alone, then mixture; (capacity, 2, F, T) log-magnitudes, or None.
        # ``arrays``: given ones (the render processes' shared map), else allocated on first use.
        self.renders, self.spectrograms = arrays if arrays is not None else (None, None)

    def __contains__(self, key: tuple[int, int]) -> bool:
        return key in self._entries

    def get(self, key: tuple[int, int]) -> int | None:
        """The entry of ``key`` (now the most recently used), or None."""
        entry = self._entries.get(key)
        if entry is not None:
            self._entries.move_to_end(key)
        return entry

    def store(self, key: tuple[int, int], render: np.ndarray) -> int | None:
        """Keep ``render`` for a new pose, in the least recently used entry when full; its entry
        (where the caller puts the spectrogram), or None with capacity 0."""
        entry = self.reserve(key)
        if entry is not None:
            self.renders[entry] = render
        return entry

    def reserve(self, key: tuple[int, int]) -> int | None:
        """The entry a new pose's render goes to (the least recently used one when full), now
        ``key``'s; None with capacity 0."""
        if not self.capacity:
            return None
        if self.renders is None:
            self.renders = np.empty(self._shapes[0], np.float32)
            if self._shapes[1] is not None:
                self.spectrograms = np.empty(self._shapes[1], np.float32)
        entry = len(self._entries) if len(self._entries) < self.capacity else self._entries.popitem(last=False)[1]
        self._entries[key] = entry
        return entry

    def clear(self) -> None:
        self._entries.clear()


POPULATE_LIMIT_BYTES = 1 << 30  # a bank up to this is mapped whole by prepare()


def _bank_bytes(bank: RirBank) -> int:
    """What a whole bank takes: source nodes x receivers x row of samples."""
    return bank.n_nodes ** 2 * bank.config.row_length * np.dtype(bank.config.storage_dtype).itemsize


def _scene_key(episode: Episode) -> tuple[str, str, int]:
    return episode.scene_split, episode.scene_preset, episode.scene_index


class BatchEnv:
    """``n_envs`` Move2Hear episode slots stepped together; all arrays are batched over slots.

    ``reset()`` starts every slot (``episodes`` forces per-slot episodes, an Episode or an index into
    the list, None entries take the next in order); ``step(actions)`` returns
    ``(obs, reward, terminated, truncated, info)``. With ``autoreset`` (default) a slot whose episode
    ended starts its next one in the same call: the returned observation is the new episode's first,
    and ``info["final_observation"]`` / ``info["final_info"]`` hold the whole batch as it was before
    those resets. Without it, stepping after an episode ended raises until ``reset()``.

    Speed options that leave every number unchanged: ``threads`` render the slots in parallel
    (each takes the next slot to render, fresh poses first); ``pose_cache`` keeps, per slot, the
    renders of up to that many poses of the current episode (at most max_steps + 1 are kept), so a
    revisited pose (turning back, Stop in near-target) skips the convolution and STFT (only the
    microphone noise is drawn anew); ``rir_spectra_mib`` (default 0: off) bounds an LRU of
    RIR spectra per (scene, source node, receiver node, heading) shared by all slots, so a fresh pose
    whose RIRs were transformed before (by any slot, in any episode) skips their FFTs
    (``RirSpectra``; 192 KiB an entry for 0.5 s RIRs). It pays where poses recur across episodes
    (many clips at few poses); random-action episodes over the test scenes hit it only ~15% of the
    time at 256 MiB, where its memory traffic costs more than it saves (docs/design/simulator.md).
    ``stored_rir_spectra`` (default False) instead reads every RIR spectrum from files stored next
    to the RIR bank (``StoredRirSpectra``: ~1 GiB of disk and page cache per 32-node scene, computed
    once): a fresh render skips the RIR gather and its FFT, ~25% of an env step's CPU.
    ``render_processes`` (default 0) starts that many processes that render fresh poses beside the
    stepping one, out of its interpreter lock (``render_worker``; on two cores, one of them with
    ``threads=1`` and stored spectra steps 16 envs ~1.5x faster than two threads); ``close()`` ends them.
    ``prepare()`` fills the RIR banks and view caches. Constructing one sets glibc's malloc to keep
    freed memory for the whole process (``m2h_ros.allocator.keep_freed_blocks``: a few MiB freed and
    taken back every step otherwise cost page faults).
    """

    def __init__(self, episodes: Sequence[Episode], library: SoundLibrary, *, n_envs: int,
                 config: EnvConfig = EnvConfig(), rir_cache_dir: Path | None = None,
                 autoreset: bool = True, threads: int = 1, pose_cache: int = 32,
                 rir_spectra_mib: float = 0.0, stored_rir_spectra: bool = False,
                 render_processes: int = 0) -> None:
        if not isinstance(config, EnvConfig):
            raise ConfigError(f"config must be an EnvConfig, got {type(config).__name__}")
        if isinstance(n_envs, bool) or not isinstance(n_envs, (int, np.integer)) or n_envs < 1:
            raise ConfigError(f"n_envs={n_envs!r} must be a positive int")
        self.episodes = list(episodes)
        if not self.episodes:
            raise ConfigError("BatchEnv needs at least one episode")
        if library.config.sample_rate != config.acoustics.sample_rate:
            raise ConfigError(f"sound library sample rate {library.config.sample_rate} differs from "
                              f"the acoustics' {config.acoustics.sample_rate}")
        if library.config.clip_len != config.stft.clip_samples:
            raise ConfigError(f"sound library clips have {library.config.clip_len} samples, the STFT "
                              f"expects {config.stft.clip_samples}")
        self.library, self.config, self.n_envs = library, config, int(n_envs)
        if isinstance(threads, bool) or not isinstance(threads, (int, np.integer)) or threads < 1:
            raise ConfigError(f"threads={threads!r} must be a positive int")
        if isinstance(pose_cache, bool) or not isinstance(pose_cache, (int, np.integer)) or pose_cache < 0:
            raise ConfigError(f"pose_cache={pose_cache!r} must be a non-negative int")
        self.autoreset, self.threads, self.rir_cache_dir = autoreset, int(threads), rir_cache_dir
        self.pose_cache = int(pose_cache)
        if isinstance(rir_spectra_mib, bool) or not isinstance(rir_spectra_mib, (int, float, np.integer)) \
                or not 0 <= rir_spectra_mib < np.inf:
            raise ConfigError(f"rir_spectra_mib={rir_spectra_mib!r} must be a finite number >= 0")
        if not isinstance(stored_rir_spectra, bool):
            raise ConfigError(f"stored_rir_spectra={stored_rir_spectra!r} must be a bool")
        if stored_rir_spectra and rir_spectra_mib:
            raise ConfigError("stored_rir_spectra=True already holds every RIR spectrum: leave rir_spectra_mib at 0")
        self.stored_rir_spectra = stored_rir_spectra
        if isinstance(render_processes, bool) or not isinstance(render_processes, (int, np.integer)) \
                or render_processes < 0:
            raise ConfigError(f"render_processes={render_processes!r} must be a non-negative int")
        self._pool = ThreadPoolExecutor(self.threads - 1) if self.threads > 1 else None
        keep_freed_blocks()   # process-wide: glibc keeps freed memory instead of re-faulting it
        self.n_samples = config.stft.clip_samples
        self.max_sources = max(len(e.source_nodes) for e in self.episodes)
        self.max_nodes = max(scene_at(*k).grid.n_nodes for k in {_scene_key(e) for e in self.episodes})
        self.max_episode_steps = max(e.max_steps for e in self.episodes)
        self._n_fft = convolution_length(clip_samples=self.n_samples, n_taps=config.acoustics.n_taps)
        self._rir_spectra = RirSpectra(self._n_fft, config.acoustics.n_taps,
                                       max_bytes=int(rir_spectra_mib * 2**20))
        self._scenes: dict[tuple[str, str, int], _SceneData] = {}
        self._index_of: dict[Episode, int] = {}
        for i, e in enumerate(self.episodes):
            self._index_of.setdefault(e, i)
        self._seed = int(config.seed)
        b, k = self.n_envs, self.max_sources
        self._current: list[Episode | None] = [None] * b
        self._slot_scene: list[_SceneData | None] = [None] * b
        self._rngs: list[np.random.Generator | None] = [None] * b
        # An episode shows at most max_steps + 1 poses: more entries would never be used.
        capacity = min(self.pose_cache, self.max_episode_steps + 1)
        # Microphone noise makes every observation's spectrogram new: then none is kept.
        self._cached_spectrograms = config.spectrogram and config.mic_noise == 0
        self._workers = None
        if render_processes:
            self._workers = RenderWorkers(RenderSetup(
                n_envs=b, max_sources=k, n_fft=self._n_fft, n_samples=self.n_samples, stft=config.stft,
                acoustics=config.acoustics, rir_cache_dir=rir_cache_dir, stored_rir_spectra=stored_rir_spectra,
                rir_spectra_mib=float(rir_spectra_mib), pose_cache=capacity), int(render_processes))
        shared = self._workers.shared if self._workers is not None else None
        self._pose_cache = [_PoseCache(capacity, self.n_samples, (config.stft.n_freq, config.stft.n_frames),
                                       spectrograms=self._cached_spectrograms,
                                       arrays=None if shared is None else shared.pose_cache(slot))
                            for slot in range(b)]
        self._renders = np.zeros((b, 2), np.int64)   # per slot: pose-cache hits, fresh renders
        self._started = np.zeros(b, np.int64)       # episodes each slot has started since reset(seed)
        self._episode_index = np.full(b, -1, np.int64)
        self._node, self._heading, self._step = (np.zeros(b, np.int64) for _ in range(3))
        self._target, self._max_steps, self._target_class = (np.zeros(b, np.int64) for _ in range(3))
        self._far, self._done = np.zeros(b, bool), np.ones(b, bool)
        self._sources = np.zeros((b, k), np.int64)
        self._n_sources = np.zeros(b, np.int64)
        self._source_weight = np.zeros(b, np.float32)  # 1 / number of sources
        # Each slot's clips' spectra; in the render processes' shared map when there are any.
        self._clip_spectra = (np.zeros((b, k, self._n_fft // 2 + 1), np.complex64) if self._workers is None
                              else self._workers.shared.clip_spectra)
        self._target_mono = np.zeros((b, self.n_samples), np.float32)

    # ------------------------------------------------------------------ spaces
    def single_observation_space(self) -> spaces.Dict:
        """The Gymnasium space of one slot's observation (what ``obs[key][i]`` satisfies)."""
        cfg, cam = self.config, self.config.camera_config
        f32, inf = np.float32, np.inf
        space = {
            "audio": spaces.Box(-inf, inf, (2, self.n_samples), f32),
            "pose": spaces.Box(-inf, inf, (3,), f32),
            "node": spaces.Discrete(self.max_nodes),
            "heading": spaces.Discrete(N_HEADINGS),
            "target_class": spaces.Discrete(len(TARGET_CATEGORIES)),
            "step": spaces.Discrete(self.max_episode_steps + 1),
        }
        if cfg.spectrogram:
            space["spectrogram"] = spaces.Box(0.0, inf, (2, cfg.stft.n_freq, cfg.stft.n_frames), f32)
        if cfg.camera:
            space["rgb"] = spaces.Box(0, 255, (cam.height, cam.width, 3), np.uint8)
            space["depth"] = spaces.Box(0.0, cam.max_depth, (cam.height, cam.width, 1), f32)
        return spaces.Dict(space)

    @property
    def current_episodes(self) -> list[Episode | None]:
        return list(self._current)

    @property
    def pose_cache_hit_rate(self) -> float:
        """Share of audio observations served from the pose cache since construction."""
        hits, fresh = self._renders.sum(axis=0)
        return float(hits / max(hits + fresh, 1))

    @property
    def render_process_ids(self) -> list[int]:
        """Process ids of the render processes (``render_processes``), for benchmarks' CPU figures."""
        return [] if self._workers is None else self._workers.process_ids

    @property
    def rir_spectra_hit_rate(self) -> float:
        """Share of the RIR spectra of fresh renders served from the RIR spectrum cache."""
        spectra = self._rir_spectra
        return float(spectra.hits / max(spectra.hits + spectra.misses, 1))

    def scene_of(self, slot: int) -> Scene:
        data = self._slot_scene[slot]
        if data is None:
            raise M2HError(f"slot {slot} has not started an episode: call reset() first")
        return data.scene

    # ------------------------------------------------------------------ control
    def reset(self, *, seed: int | None = None, episodes: Sequence[Episode | int | None] | None = None
              ) -> tuple[Observation, dict[str, Any]]:
        """Start every slot; ``seed`` re-seeds the episode order and restarts it."""
        if seed is not None:
            if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or seed < 0:
                raise ConfigError(f"seed={seed!r} must be a non-negative int")
            self._seed = int(seed)
            self._started[:] = 0
        if episodes is not None and len(episodes) != self.n_envs:
            raise ConfigError(f"episodes has {len(episodes)} entries for {self.n_envs} slots")
        slots = np.arange(self.n_envs)
        self._start_slots(slots, [None] * self.n_envs if episodes is None else episodes)
        obs, info = self._observe(slots)
        info["done"] = np.zeros(self.n_envs, bool)
        return obs, info

    def step(self, actions, *, hold=None) -> tuple[Observation, np.ndarray, np.ndarray, np.ndarray, dict[str, Any]]:
        """One action per slot; ``hold`` (B,) bool: slots that stay as they are this step whatever
        their action (a real-time run whose controller missed the step), which still counts."""
        actions = np.asarray(actions)
        hold = np.zeros(self.n_envs, bool) if hold is None else np.asarray(hold, bool)
        if hold.shape != (self.n_envs,):
            raise ConfigError(f"hold must be {self.n_envs} bools, got shape {hold.shape}")
        if actions.shape != (self.n_envs,) or not np.issubdtype(actions.dtype, np.integer) \
                or actions.min() < 0 or actions.max() >= N_ACTIONS:
            raise ConfigError(f"actions must be {self.n_envs} ints in [0, {N_ACTIONS}), got {actions!r}")
        if self._done.any():
            raise M2HError(f"slots {np.flatnonzero(self._done).tolist()} have ended their episode "
                           f"(or never started): call reset()")
        cfg = self.config
        before = self._distance()
        for data, slots in self._groups(np.arange(self.n_envs)):   # rows = slots here
            moving = slots[(actions[slots] == MOVE_FORWARD) & ~hold[slots]]
            self._node[moving] = data.scene.grid.forward[self._node[moving], self._heading[moving]]
        self._heading = np.where(hold, self._heading,
                                 np.where(actions == TURN_LEFT, (self._heading + 1) % N_HEADINGS,
                                          np.where(actions == TURN_RIGHT, (self._heading - 1) % N_HEADINGS,
                                                   self._heading)))
        self._step += 1
        after = self._distance()
        terminated = (actions == STOP) & self._far & ~hold
        success = terminated & (self._node == self._target)
        truncated = ~terminated & (self._step >= self._max_steps)
        reward = (cfg.distance_reward * (before - after) - cfg.step_penalty
                  + cfg.success_reward * success).astype(np.float32)
        self._done = terminated | truncated
        obs, info = self._observe(np.arange(self.n_envs))
        info.update(done=self._done.copy(), success=success)
        if self.autoreset and self._done.any():
            ended = np.flatnonzero(self._done)
            final_obs, final_info = obs, dict(info)
            self._start_slots(ended, [None] * len(ended))
            fresh_obs, fresh_info = self._observe(ended)
            restarted = ("target_monaural", "target_binaural", "target_delay", "geodesic_distance", "at_target",
                         "episode_index")
            if len(ended) == self.n_envs:   # all at once (synchronous episodes): no batch to copy
                obs = fresh_obs
                info = {key: fresh_info[key] if key in restarted else value.copy() for key, value in info.items()}
            else:
                final_obs = {key: value.copy() for key, value in obs.items()}
                final_info = {key: value.copy() for key, value in info.items()}
                for key, value in fresh_obs.items():
                    obs[key][ended] = value
                for key in restarted:
                    info[key][ended] = fresh_info[key]
            info["final_observation"], info["final_info"] = final_obs, final_info
        return obs, reward, terminated, truncated, info

    def prepare(self, *, workers: int = 1, progress: bool = True) -> None:
        """Build every RIR bank (and the stored RIR spectra, if used) and render every camera view of
        the episodes' scenes now (before timing, or before forking workers that would otherwise each
        fill their own caches), and map the pages of the files the renders read into this process and
        the render processes (no page faults inside steps) where they fit POPULATE_LIMIT_BYTES: a large
        building's bank (139 nodes: 3.2 GiB) stays mapped on demand, its memory what the episodes touch."""
        keys = sorted({_scene_key(e) for e in self.episodes})
        for key in keys:
            data = self._scene_data(key)
            populate = data.spectra is None and _bank_bytes(data.bank) <= POPULATE_LIMIT_BYTES
            data.bank.build(workers=workers, progress=progress, populate_pages=populate)
            if data.spectra is not None:
                data.spectra.build(populate_pages=True)
            if data.views is not None:
                data.views.prerender()
        if self._workers is not None:
            self._workers.prepare(keys)

    def target_rirs(self, slots: Sequence[int]) -> np.ndarray:
        """(B, 2, T) binaural RIRs from each slot's target to its current pose: what the target alone
        as heard is convolved with (``info["target_binaural"]`` = clip * RIR, first S samples)."""
        return np.concatenate([self._slot_scene[s].bank.rirs([self._sources[s, 0]], [self._node[s]], [self._heading[s]])
                               for s in slots])

    def close(self) -> None:
        if self._pool is not None:
            self._pool.shutdown()
        if self._workers is not None:
            self._workers.close()
        self._scenes.clear()
        self._rir_spectra.clear()

    def state(self) -> dict[str, Any]:
        """Where every slot stands (plain types), for :meth:`restore` in a new env over the same
        episode list: training checkpoints resume exactly. The current observation is not part of
        it (re-rendering would draw the microphone noise again): keep the one ``step`` returned."""
        if (self._episode_index < 0).any():
            raise M2HError("BatchEnv.state(): a slot plays an episode that is not in the list")
        return {"n_envs": self.n_envs, "n_episodes": len(self.episodes), "seed": self._seed,
                "started": self._started.tolist(), "episode_index": self._episode_index.tolist(),
                "node": self._node.tolist(), "heading": self._heading.tolist(), "step": self._step.tolist(),
                "done": self._done.tolist(), "rng": [rng.bit_generator.state for rng in self._rngs]}

    def restore(self, state: dict[str, Any]) -> None:
        """Put every slot where :meth:`state` found it (pose caches start empty: same numbers)."""
        if (state["n_envs"], state["n_episodes"]) != (self.n_envs, len(self.episodes)):
            raise ConfigError(f"BatchEnv.restore(): state of {state['n_envs']} slots over {state['n_episodes']} "
                              f"episodes, this env has {self.n_envs} over {len(self.episodes)}")
        self._seed = int(state["seed"])
        self._start_slots(np.arange(self.n_envs), [int(index) for index in state["episode_index"]])
        for slot in range(self.n_envs):
            self._rngs[slot].bit_generator.state = state["rng"][slot]
        for name in ("started", "node", "heading", "step", "done"):
            getattr(self, f"_{name}")[:] = state[name]

    # ------------------------------------------------------------------ internals
    def _episode_for(self, slot: int, count: int) -> int:
        """Index of the ``count``-th episode of ``slot``: slots take turns along a seeded order."""
        epoch, position = divmod(count * self.n_envs + slot, len(self.episodes))
        if not self.config.shuffle:
            return position
        return int(_permutation(len(self.episodes), self._seed, epoch)[position])

    def _scene_data(self, key: tuple[str, str, int]) -> _SceneData:
        data = self._scenes.get(key)
        if data is None:
            scene = scene_at(*key)
            views = CameraViews(scene, self.config.camera_config) if self.config.camera else None
            bank = RirBank(scene, self.config.acoustics, cache_dir=self.rir_cache_dir, progress=False)
            spectra = StoredRirSpectra(bank, self._n_fft) if self.stored_rir_spectra else None
            data = self._scenes[key] = _SceneData(scene, bank, views, spectra)
        return data

    def _start_slots(self, slots: np.ndarray, episodes: Sequence[Episode | int | None]) -> None:
        """Start an episode in each slot (None: its next in order); the clips of all of them are
        transformed in one FFT (pocketfft does 1-2 rows at a time 2-3x slower per row)."""
        clips = [self._start(int(slot), episode) for slot, episode in zip(slots, episodes)]
        # The render processes wait meanwhile: their cores take FFT threads (same numbers per row).
        workers = self.threads + (0 if self._workers is None else len(self._workers.process_ids))
        spectra = sfft.rfft(np.concatenate(clips), self._n_fft, axis=-1, workers=workers)
        first = 0
        for slot, count in zip(slots, map(len, clips)):
            self._clip_spectra[slot, :count] = spectra[first:first + count]
            first += count

    def _start(self, slot: int, episode: Episode | int | None) -> np.ndarray:
        """Put ``slot`` at the start of ``episode``; its clips (sources, S) float32, whose spectra the
        caller stores."""
        if episode is None:
            index = self._episode_for(slot, int(self._started[slot]))
            episode = self.episodes[index]
        elif isinstance(episode, (int, np.integer)) and not isinstance(episode, bool):
            if not 0 <= episode < len(self.episodes):
                raise ConfigError(f"episode index {episode} is not in [0, {len(self.episodes)})")
            index, episode = int(episode), self.episodes[int(episode)]
        elif isinstance(episode, Episode):
            index = self._index_of.get(episode, -1)   # -1: not from the list
        else:
            raise ConfigError(f"episode must be an Episode, an index or None, got {type(episode).__name__}")
        self._started[slot] += 1
        data = self._scene_data(_scene_key(episode))
        n_sources, n_nodes = len(episode.source_nodes), data.scene.grid.n_nodes
        if not 1 <= n_sources <= self.max_sources:
            raise EpisodeError(f"episode {episode.episode_id} has {n_sources} sources; this env holds "
                               f"1..{self.max_sources} (the most in its episode list)")
        if not all(0 <= n < n_nodes for n in (episode.start_node, *episode.source_nodes)) \
                or not 0 <= episode.start_heading < N_HEADINGS:
            raise EpisodeError(f"episode {episode.episode_id} names nodes outside scene "
                               f"{data.scene.scene_id} ({n_nodes} nodes) or a bad heading")
        if episode.target_category not in TARGET_CATEGORIES:
            raise EpisodeError(f"episode {episode.episode_id}: target category "
                               f"{episode.target_category!r} is not one of {TARGET_CATEGORIES}")
        clips = np.stack([self.library.clip(c) for c in episode.source_clips]).astype(np.float32)
        self._current[slot], self._slot_scene[slot] = episode, data
        self._episode_index[slot] = index
        self._node[slot], self._heading[slot], self._step[slot] = episode.start_node, episode.start_heading, 0
        self._target[slot], self._max_steps[slot] = episode.target_node, episode.max_steps
        self._far[slot], self._done[slot] = episode.task == "far_target", False
        self._target_class[slot] = TARGET_CATEGORIES.index(episode.target_category)
        self._n_sources[slot] = n_sources   # later rows of _sources and _clip_spectra are unused
        self._sources[slot, :n_sources] = episode.source_nodes
        self._source_weight[slot] = 1.0 / n_sources
        self._target_mono[slot] = clips[0]
        self._rngs[slot] = np.random.default_rng([episode.seed, _NOISE_SALT])
        self._pose_cache[slot].clear()
        return clips

    def _groups(self, slots: np.ndarray):
        """(scene data, rows of ``slots``) for each scene the given slots are in."""
        by_scene: dict[int, list[int]] = {}
        for row, slot in enumerate(slots.tolist()):
            by_scene.setdefault(id(self._slot_scene[slot]), []).append(row)
        for rows in by_scene.values():
            yield self._slot_scene[slots[rows[0]]], np.asarray(rows, np.int64)

    def _distance(self) -> np.ndarray:
        """(B,) geodesic metres from each slot's node to its target."""
        out = np.zeros(self.n_envs, np.float32)
        for data, slots in self._groups(np.arange(self.n_envs)):
            out[slots] = data.scene.grid.geodesic[self._node[slots], self._target[slots]]
        return out

    def _observe(self, slots: np.ndarray) -> tuple[Observation, dict[str, Any]]:
        """Observation and ground truth of the given slots at their current poses."""
        n, cfg, cam, f = len(slots), self.config, self.config.camera_config, self.config.stft
        node, heading, target = self._node[slots], self._heading[slots], self._target[slots]
        outputs = (np.empty((n, 2, self.n_samples), np.float32),          # audio
                   np.empty((n, 2, self.n_samples), np.float32),          # target_binaural
                   np.empty((n, 2, f.n_freq, f.n_frames), np.float32) if cfg.spectrogram else None)
        # Rows are independent, so the threads render them in parallel (numpy and pocketfft release
        # the GIL), taking one row at a time from a shared iterator (next() on it is atomic), fresh
        # renders first: one costs ~25x a pose-cache hit, so fixed chunks would leave a thread idle
        # while the other renders. The results do not depend on which thread renders a row.
        keys = list(zip(node.tolist(), heading.tolist()))
        fresh = [key not in self._pose_cache[slot] for slot, key in zip(slots.tolist(), keys)]
        if self._workers is None:
            queue = iter(sorted(range(n), key=fresh.__getitem__, reverse=True))   # stable: fresh first
        else:   # the render processes start on the fresh poses now; this process takes the cache hits
            fresh_rows = [row for row in range(n) if fresh[row]]
            render_jobs = [self._job(int(slots[row]), keys[row]) for row in fresh_rows]
            self._workers.start(render_jobs)
            queue = iter([row for row in range(n) if not fresh[row]])
        jobs = [self._pool.submit(self._render_rows, slots, keys, queue, outputs)
                for _ in range(min(self.threads, n) - 1)]
        positions = np.empty((n, 2), np.float64)
        geodesic = np.empty(n, np.float32)
        target_distance = np.empty(n, np.float64)
        if cfg.camera:
            rgb = np.empty((n, cam.height, cam.width, 3), np.uint8)
            depth = np.empty((n, cam.height, cam.width, 1), np.float32)
        for data, rows in self._groups(slots):
            grid = data.scene.grid
            positions[rows] = grid.positions[node[rows]]
            geodesic[rows] = grid.geodesic[node[rows], target[rows]]
            target_distance[rows] = np.linalg.norm(grid.positions[target[rows]] - positions[rows], axis=1)
            if cfg.camera:
                data.views.copy_views(node[rows], heading[rows], rgb, depth[..., 0], rows.tolist())
        self._render_rows(slots, keys, queue, outputs)
        for job in jobs:
            job.result()
        if self._workers is not None:
            self._render_beside_workers(fresh_rows, render_jobs, outputs)
        audio, target_binaural, spectrogram = outputs
        pose = np.column_stack([positions, heading_angle(heading)]).astype(np.float32)
        obs: Observation = {
            "audio": audio, "pose": pose, "node": node,
            "heading": heading, "target_class": self._target_class[slots], "step": self._step[slots]}
        if cfg.spectrogram:
            obs["spectrogram"] = spectrogram
        if cfg.camera:
            obs["rgb"], obs["depth"] = rgb, depth
        acoustics = cfg.acoustics
        target_delay = (np.maximum(target_distance, acoustics.min_distance) / acoustics.speed_of_sound
                        * acoustics.sample_rate)
        info = {"target_monaural": self._target_mono[slots], "target_binaural": target_binaural,
                "target_delay": target_delay,
                "geodesic_distance": geodesic, "at_target": node == target,
                "episode_index": self._episode_index[slots],
                "done": np.zeros(n, bool), "success": np.zeros(n, bool)}
        return obs, info

    def _render_beside_workers(self, fresh_rows: list[int], jobs: list[RenderJob],
                               outputs: tuple[np.ndarray, np.ndarray, np.ndarray]) -> None:
        """Render fresh poses beside the render processes until none is left, then place them all:
        its own while the processes finish theirs, then theirs."""
        shared, own = self._workers.shared, []
        while (index := self._workers.claim()) is not None:
            render, spectrogram = shared.destination(jobs[index], index)
            render[...] = self._convolve(jobs[index].slot)
            if spectrogram is not None:
                log_magnitude_into(render[2:], spectrogram, config=self.config.stft)
            own.append(index)

        def place(index: int) -> None:
            self._place(fresh_rows[index], jobs[index].slot, *shared.destination(jobs[index], index), outputs,
                        fresh=True)

        for index in own:
            place(index)
        self._workers.finish()
        for index in sorted(set(range(len(jobs))) - set(own)):
            place(index)

    def _render_rows(self, slots: np.ndarray, keys: list[tuple[int, int]], rows,
                     outputs: tuple[np.ndarray, np.ndarray, np.ndarray]) -> None:
        """Render the rows that the iterator ``rows`` hands out: mixture (+ noise), target alone,
        log-magnitude STFT, into ``outputs`` (audio, target_binaural, spectrogram).

        Poses an episode already visited come from the slot's pose cache (same numbers); the
        microphone noise is drawn afresh at every step all the same.
        """
        for row in rows:
            slot, key = int(slots[row]), keys[row]
            entry = self._pose_cache[slot].get(key)
            if entry is None:
                self._place_fresh(row, slot, key, self._convolve(slot), outputs)
            else:
                self._place_cached(row, slot, entry, outputs)

    def _place_fresh(self, row: int, slot: int, key: tuple[int, int], render: np.ndarray,
                     outputs: tuple[np.ndarray, np.ndarray, np.ndarray]) -> None:
        """A fresh render (4, S) of ``row``'s pose into the slot's pose cache and ``outputs``."""
        cache = self._pose_cache[slot]
        stored = cache.store(key, render)
        spectrogram = self._place(row, slot, render, None, outputs, fresh=True)
        if stored is not None and self._cached_spectrograms:   # then _place computed it
            cache.spectrograms[stored] = spectrogram

    def _place_cached(self, row: int, slot: int, entry: int,
                      outputs: tuple[np.ndarray, np.ndarray, np.ndarray]) -> None:
        """Pose-cache entry ``entry`` of ``slot`` into ``outputs``."""
        cache = self._pose_cache[slot]
        spectrogram = cache.spectrograms[entry] if self._cached_spectrograms else None
        self._place(row, slot, cache.renders[entry], spectrogram, outputs, fresh=False)

    def _place(self, row: int, slot: int, render: np.ndarray, spectrogram: np.ndarray | None,
               outputs: tuple[np.ndarray, np.ndarray, np.ndarray | None], *, fresh: bool) -> np.ndarray | None:
        """A render (4, S) of ``row``'s pose into ``outputs``, plus fresh microphone noise, and its
        log-magnitude: ``spectrogram`` where it is known (without noise), else computed; returned
        (None when the observations hold no spectrogram)."""
        audio, target_binaural, spectrograms = outputs
        self._renders[slot, int(fresh)] += 1   # each slot is placed by one thread
        target_binaural[row], audio[row] = render[:2], render[2:]
        if self.config.mic_noise > 0:
            rms = np.sqrt(np.mean(np.square(audio[row])))
            noise = self._rngs[slot].standard_normal((2, self.n_samples), dtype=np.float32)
            audio[row] += (self.config.mic_noise * rms) * noise
            spectrogram = None
        if spectrograms is None:
            return None
        if spectrogram is None:
            return log_magnitude_into(audio[row], spectrograms[row], config=self.config.stft)
        spectrograms[row] = spectrogram
        return spectrograms[row]

    def _convolve(self, slot: int) -> np.ndarray:
        """(4, S) view: the slot's target alone at its pose (rows 0-1), then the clean mixture (rows 2-3)."""
        count, data = int(self._n_sources[slot]), self._slot_scene[slot]
        found = source_spectra(data.bank, data.spectra, self._rir_spectra, self._sources[slot, :count].tolist(),
                               int(self._node[slot]), int(self._heading[slot]))
        return render_pose(found, self._clip_spectra[slot], self._source_weight[slot], n_fft=self._n_fft,
                           n_samples=self.n_samples)

    def _job(self, slot: int, key: tuple[int, int]) -> RenderJob:
        """What a render process needs to render ``slot`` at the fresh pose ``key``, and where: the
        pose-cache entry this reserves for it (-1 without a pose cache)."""
        count, entry = int(self._n_sources[slot]), self._pose_cache[slot].reserve(key)
        return RenderJob(slot, _scene_key(self._current[slot]), tuple(self._sources[slot, :count].tolist()),
                         *key, spectrogram=self._cached_spectrograms, entry=-1 if entry is None else entry)


@lru_cache(maxsize=8)
def _permutation(n: int, seed: int, epoch: int) -> np.ndarray:
    return np.random.default_rng([seed, epoch]).permutation(n)


def _first(batch: dict[str, Any]) -> dict[str, Any]:
    """Slot 0 of every batched entry (nested dicts too)."""
    return {key: _first(value) if isinstance(value, dict) else value[0] for key, value in batch.items()}


class MoveHearEnv(gymnasium.Env):
    """Single-env Gymnasium API over a one-slot ``BatchEnv`` (same numbers, no auto-reset).

    ``reset(seed=..., options={"episode": Episode or index})`` plays a given episode; without it the
    next one of the seeded order. Actions: Discrete(4) = STOP, MOVE_FORWARD, TURN_LEFT, TURN_RIGHT.
    Observations (``observation_space``): ``audio`` (2, 16000) binaural float32, ``pose`` (x, y, yaw),
    ``node``, ``heading``, ``target_class``, ``step``, and with the camera ``rgb`` and ``depth``. ``info``
    holds the ground truth for scoring and rewards, never for a policy: ``target_monaural``,
    ``target_binaural``, ``target_delay``, ``geodesic_distance``, ``at_target``, ``success``.
    """

    metadata = {"render_modes": []}

    def __init__(self, episodes: Sequence[Episode], library: SoundLibrary, *, config: EnvConfig = EnvConfig(),
                 rir_cache_dir: Path | None = None, threads: int = 1, pose_cache: int = 32) -> None:
        self.batch = BatchEnv(episodes, library, n_envs=1, config=config, rir_cache_dir=rir_cache_dir,
                              autoreset=False, threads=threads, pose_cache=pose_cache)
        self.action_space = spaces.Discrete(N_ACTIONS)
        self.observation_space = self.batch.single_observation_space()

    @property
    def episode(self) -> Episode | None:
        return self.batch.current_episodes[0]

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None
              ) -> tuple[Observation, dict[str, Any]]:
        super().reset(seed=seed)
        unknown = set(options or {}) - {"episode"}
        if unknown:
            raise ConfigError(f"unknown reset option(s) {sorted(unknown)}; known: ['episode']")
        episode = (options or {}).get("episode")
        obs, info = self.batch.reset(seed=seed, episodes=None if episode is None else [episode])
        return _first(obs), _first(info)

    def step(self, action) -> tuple[Observation, float, bool, bool, dict[str, Any]]:
        obs, reward, terminated, truncated, info = self.batch.step(np.asarray([action], np.int64))
        return _first(obs), float(reward[0]), bool(terminated[0]), bool(truncated[0]), _first(info)

    def close(self) -> None:
        self.batch.close()
