"""Offline replay scoring: recompute a recorded run's scores from its bag and check the live ones.

A bag of the pipeline holds, per step k of an episode, the mixture (``audio``), the refined estimate
(``separator/refined``), the ground truth (``/ground_truth/target``), the pose (``agent_pose``) and the
action that brought the robot there (``agent_pose.last_action``; ``cmd`` names the controller), plus the live evaluator's ``scores/step`` and
``scores/episode``. :func:`replay_bag` streams the bag (:class:`~m2h_ros.io.mcap_stream.BagStream`),
decodes only those topics, groups messages by (episode id, step), scores complete steps in small
batches with :func:`~m2h_ros.core.audio.scoring.score_magnitude` and releases them, and builds each
episode with :class:`~m2h_ros.core.results.EpisodeTracker`, exactly as the live evaluator does. Memory
holds at most a few open episodes' unscored steps, whatever the bag's length.

On several cores (``ReplayConfig.score_processes``) this process still reads every chunk once and
groups the steps, and child processes score the batches with it (it scores a batch itself whenever each
child has three waiting); the scores are taken in reading order, so the results are the same, bit for
bit, as one process's. Should a batch fail to score in a child (an estimate with NaN), the bag is
replayed again in one process, so that what is reported about it, and in which order, is what one
process reports.

Recomputed and live figures are compared at ``|replayed - live| <= atol`` (default 1e-3: dB for
SI-SDR, the metric's own unit otherwise; booleans and step counts exactly). Problems with the bag
(damaged, foreign, an episode that cannot be completed) are collected as BagErrors; everything else
that can be scored is.
"""

from __future__ import annotations

import csv
import math
import multiprocessing
import os
from collections import deque
from collections.abc import Iterable, Iterator, Sequence
from concurrent.futures import Future, ProcessPoolExecutor
from multiprocessing.shared_memory import SharedMemory
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np

from m2h_ros import topics
from m2h_ros.allocator import keep_freed_blocks
from m2h_ros.core.audio.scoring import StepScores, StepTruth, score_magnitude
from m2h_ros.core.audio.stft import DEFAULT_STFT, StftConfig
from m2h_ros.core.results import METRICS, EpisodeResult, EpisodeTracker, plot_si_sdr_vs_step, write_results
from m2h_ros.core.world.episodes import STOP
from m2h_ros.errors import AudioError, BagError, ConfigError
from m2h_ros.io.mcap_stream import BagStream, StreamStats
from m2h_ros.io.msg_defs import typestore

PKG = "m2h_msgs/msg/"
# Topic -> type replay decodes; the parts of a step that scoring needs are PARTS.
EXPECTED_TYPES = {
    topics.EPISODE: PKG + "EpisodeInfo", topics.AUDIO: PKG + "BinauralAudio", topics.REFINED: PKG + "Spectrogram",
    topics.GROUND_TRUTH: PKG + "GroundTruth", topics.AGENT_POSE: PKG + "AgentPose",
    topics.COMMAND: PKG + "MotionCommand", topics.STEP_SCORE: PKG + "StepScore",
    topics.EPISODE_SCORE: PKG + "EpisodeScore",
}
PARTS = (topics.AUDIO, topics.REFINED, topics.GROUND_TRUTH, topics.AGENT_POSE)
LIVE_TOPICS = (topics.STEP_SCORE, topics.EPISODE_SCORE)
FAR_TARGET = "far_target"
EPISODE_FIELDS = ("si_sdr", "si_sdr_mixture_phase", "stft_distance", "mean_si_sdr", "success", "spl",
                  "path_length", "shortest_path", "steps")


@dataclass(frozen=True)
class ReplayConfig:
    namespace: str = "/"  # the graph's namespace: relative topic names resolve under it
    atol: float = 1e-3  # tolerance of replayed vs live figures
    # Complete steps scored together (speed; memory stays bounded by it). Beyond 8 a batch is no faster,
    # and smaller ones share the work between processes more evenly.
    batch_steps: int = 8
    # Processes scoring the batches: this one, between its reads, and score_processes - 1 child processes
    # (the same numbers). Scoring is over half of a step's CPU time, reading the rest, so N processes keep
    # N cores busy without a third process taking turns with two on two cores.
    score_processes: int = 1
    # An unfinished episode is given up once this many newer ones have begun. In a pipeline bag the
    # separator and the evaluator run behind the simulator by up to the sim's max_evaluator_lag (<= 100
    # observations, ~5 near-target episodes), so an episode's last estimates can come after newer
    # episodes' first observations. Memory is bounded by the pending steps, not by this count.
    open_episodes: int = 8

    def __post_init__(self) -> None:
        if not self.namespace.startswith("/"):
            raise ConfigError(f"ReplayConfig.namespace must be absolute, got {self.namespace!r}")
        if not (self.atol >= 0 and math.isfinite(self.atol)):
            raise ConfigError(f"ReplayConfig.atol must be finite and >= 0, got {self.atol!r}")
        if self.batch_steps < 1 or self.open_episodes < 1 or self.score_processes < 1:
            raise ConfigError("ReplayConfig.batch_steps, open_episodes and score_processes must be >= 1")

    def topic(self, name: str) -> str:
        return name if name.startswith("/") else f"{self.namespace.rstrip('/')}/{name}"


@dataclass(frozen=True)
class Mismatch:
    episode_id: str
    step: int | None  # None: an episode-level figure
    metric: str
    live: float
    replayed: float


@dataclass
class Comparison:
    """Replayed vs live scores of one bag."""

    steps: int = 0  # step scores present in both
    episodes: int = 0
    max_diff: dict[str, float] = field(default_factory=dict)  # metric -> largest |replayed - live|
    mismatches: list[Mismatch] = field(default_factory=list)
    live_only: int = 0  # live scores of steps/episodes replay could not score
    replayed_only: int = 0  # replayed steps/episodes the bag holds no live score of

    def check(self, episode_id: str, step: int | None, metric: str, live: float, replayed: float,
              atol: float) -> None:
        live, replayed = float(live), float(replayed)
        same_nan = math.isnan(live) and math.isnan(replayed)
        diff = 0.0 if same_nan else abs(replayed - live)
        if not same_nan:
            self.max_diff[metric] = max(self.max_diff.get(metric, 0.0), diff if diff == diff else math.inf)
        if not same_nan and not diff <= atol:
            self.mismatches.append(Mismatch(episode_id, step, metric, live, replayed))


def _only_stft_distance_differs(comparison: Comparison) -> bool:
    """Every step's STFT distance differs from the live one and nothing else does."""
    step_stft = sum(m.metric == "stft_distance" and m.step is not None for m in comparison.mismatches)
    others = any("stft_distance" not in m.metric for m in comparison.mismatches)
    return step_stft == comparison.steps and not others


@dataclass
class BagReplay:
    bag: Path
    results: list[EpisodeResult]
    comparison: Comparison
    problems: list[BagError]
    notes: list[str]
    stats: StreamStats
    steps_scored: int

    @property
    def ok(self) -> bool:
        return not self.problems and not self.comparison.mismatches


@dataclass
class _Step:
    audio: np.ndarray | None = None  # (2, N)
    refined: np.ndarray | None = None  # (F, T) linear magnitude
    stft: StftConfig | None = None
    truth: Any = None  # the GroundTruth message
    position: np.ndarray | None = None

    def missing(self) -> list[str]:
        have = {topics.AUDIO: self.audio, topics.REFINED: self.refined, topics.GROUND_TRUTH: self.truth,
                topics.AGENT_POSE: self.position}
        return [name for name, value in have.items() if value is None]


@dataclass
class _Episode:
    episode_id: str
    order: int  # how many episodes began before it
    info: Any = None  # EpisodeInfo message
    steps: dict[int, _Step] = field(default_factory=dict)
    actions: dict[int, int] = field(default_factory=dict)
    controller: str = ""
    tracker: EpisodeTracker | None = None
    next_obs: int = 0
    next_act: int = 0
    first_stop: int | None = None  # step of the first Stop action
    ready: list[tuple[int, _Step]] = field(default_factory=list)

    @property
    def last(self) -> int | None:
        """The last observation's step: max_steps, or in far-target the one after a Stop."""
        if self.info is None:
            return None
        last = int(self.info.max_steps)
        if self.info.task == FAR_TARGET and self.first_stop is not None:
            last = min(last, self.first_stop + 1)
        return last


@dataclass
class _Batch:
    """Steps of an episode handed to scoring: their scores, or a child process's promise of them and the
    shared memory holding its arrays."""

    episode: _Episode
    group: list[tuple[int, _Step]]
    scores: StepScores | Future
    block: SharedMemory | None = None


@dataclass
class _End:
    """An episode all of whose steps and actions were read: finished once its batches are applied."""

    episode: _Episode


class _Diverged(Exception):
    """A batch failed to score in a child process: one process would have reported it elsewhere."""


# A batch's arrays in a shared memory block: estimate (B, F, T), mixture (B, 2, N), the target's dry clip
# (B, N) and as heard (B, 2, N), float32, one after the other. The scoring processes read them there: no
# copy through a pipe (which cost as much as scoring saved).
_ATTACHED: dict[str, SharedMemory] = {}  # in a scoring process: the blocks it has opened


def _views(block: SharedMemory, shapes: Sequence[tuple[int, ...]]) -> list[np.ndarray]:
    arrays, offset = [], 0
    for shape in shapes:
        arrays.append(np.ndarray(shape, np.float32, buffer=block.buf, offset=offset))
        offset += 4 * math.prod(shape)
    return arrays


def _score_shared(name: str, shapes: Sequence[tuple[int, ...]], config: StftConfig) -> StepScores:
    """score_magnitude of the batch in shared memory block ``name`` (run in a scoring process)."""
    if name not in _ATTACHED:
        _ATTACHED[name] = SharedMemory(name=name)
    magnitude, mixture, monaural, binaural = _views(_ATTACHED[name], shapes)
    return score_magnitude(magnitude, mixture, StepTruth(monaural, binaural), config=config)


def _scoring_pool(processes: int) -> ProcessPoolExecutor:
    # Forked where the platform can: a child starts in milliseconds, not an import's seconds.
    method = "fork" if "fork" in multiprocessing.get_all_start_methods() else "spawn"
    return ProcessPoolExecutor(processes, mp_context=multiprocessing.get_context(method))


def _pose_xy(msg) -> np.ndarray:
    return np.array([msg.pose.position.x, msg.pose.position.y], np.float64)


def _audio(msg, what: str) -> np.ndarray:
    samples = np.asarray(msg.samples, np.float32)
    channels = int(msg.channels)
    if channels < 1 or samples.size % channels:
        raise BagError(f"{what}: {samples.size} samples do not split into {channels} channel(s)")
    return samples.reshape(channels, -1)


def _spectrogram(msg, what: str) -> tuple[np.ndarray, StftConfig]:
    shape = tuple(int(s) for s in msg.shape)
    data = np.asarray(msg.data, np.float32)
    if not shape or data.size != math.prod(shape):
        raise BagError(f"{what}: {data.size} values for shape {list(shape)}")
    values = data.reshape(shape)
    if msg.layout == "CFT" and shape[0] == 1:
        values = values[0]
    elif msg.layout != "FT":
        raise BagError(f"{what}: layout {msg.layout!r} shape {list(shape)} is not one monaural FT spectrogram")
    if msg.log_magnitude:
        values = np.expm1(values)
    if (msg.n_fft, msg.hop_length) != (DEFAULT_STFT.n_fft, DEFAULT_STFT.hop_length):
        raise BagError(f"{what}: STFT n_fft={msg.n_fft}, hop={msg.hop_length} is not the paper's "
                       f"({DEFAULT_STFT.n_fft}, {DEFAULT_STFT.hop_length})")
    return values, StftConfig(sample_rate=int(msg.sample_rate) or DEFAULT_STFT.sample_rate)


class _Replayer:
    def __init__(self, bag: Path, config: ReplayConfig) -> None:
        keep_freed_blocks()  # process-wide: each batch's arrays reuse the last one's memory, not fresh pages
        self.bag = bag
        self.config = config
        self.store = typestore()
        self.topic_of = {config.topic(name): name for name in EXPECTED_TYPES}  # bag topic -> our name
        self.stream = BagStream(bag)
        self.problems = self.stream.problems  # one list: the stream's and ours, in order found
        self.notes: list[str] = []
        self.open: dict[str, _Episode] = {}
        self.closed: set[str] = set()  # episodes scored or given up: later messages are ignored
        self.begun = 0
        self.results: list[EpisodeResult] = []
        self.comparison = Comparison()
        self.live_steps: dict[tuple[str, int], Any] = {}
        self.replayed_steps: dict[tuple[str, int], tuple[float, float, float]] = {}
        self.live_episodes: dict[str, Any] = {}
        self.replayed_episodes: dict[str, EpisodeResult] = {}
        self.usable: dict[str, bool] = {}  # bag topic -> its type is the expected, known one
        self.seen: dict[str, int] = {}
        self.steps_scored = 0
        self.order: dict[str, int] = {}  # episode id -> how many episodes began before it
        self.children = config.score_processes - 1
        self.pool = _scoring_pool(self.children) if self.children else None
        # Batches being scored and episode ends, applied in reading order; at most this many in flight.
        self.pending: deque[_Batch | _End] = deque()
        self.in_flight = 4 * config.score_processes
        self.blocks: list[SharedMemory] = []  # every shared memory block made
        self.free_blocks: list[SharedMemory] = []

    def problem(self, text: str) -> None:
        self.problems.append(BagError(f"{self.bag}: {text}"))

    # --- reading ---------------------------------------------------------------------------------
    def run(self) -> BagReplay:
        try:
            return self._run()
        finally:
            if self.pool is not None:
                self.pool.shutdown(cancel_futures=True)
            for block in self.blocks:
                block.close()
                block.unlink()

    def _run(self) -> BagReplay:
        for raw in self.stream.messages(topics=set(self.topic_of)):
            name = self.topic_of[raw.topic]
            if not self._usable(raw.topic, name):
                continue
            try:
                message = self.store.deserialize_cdr(raw.data, raw.msgtype)
            except Exception as exc:  # rosbags raises several types for garbled CDR
                self.problem(f"cannot decode a {raw.msgtype} on {raw.topic} ({exc}); message skipped")
                continue
            self.seen[name] = self.seen.get(name, 0) + 1
            try:
                self._handle(name, message)
            except BagError as exc:
                self.problem(str(exc))
        for episode in list(self.open.values()):
            self._give_up(episode, "the bag ends before it does")
        self._apply_pending(wait=True)
        self._summarise_topics()
        c = self.comparison
        # In the order the episodes began and the steps came, however long each pair took to complete
        rank = {name: k for k, name in enumerate([*METRICS, *(f"episode_{m}" for m in EPISODE_FIELDS)])}
        c.mismatches.sort(key=lambda m: (self.order[m.episode_id], m.step is None, m.step or 0,
                                         rank.get(m.metric, len(rank))))
        c.live_only += len(self.live_steps) + len(self.live_episodes)
        c.replayed_only += len(self.replayed_steps) + len(self.replayed_episodes)
        if c.steps and _only_stft_distance_differs(c):
            self.notes.append("every live STFT distance differs while every SI-SDR agrees: the bag was most likely "
                              "recorded by a 0.x version, whose STFT distance was a Frobenius norm (this "
                              "version's is the original code's, docs/design/separator.md)")
        return BagReplay(self.bag, self.results, c, self.problems, self.notes, self.stream.stats,
                         self.steps_scored)

    def _usable(self, topic: str, name: str) -> bool:
        if topic not in self.usable:
            channel = self.stream.channels.get(topic)
            expected = EXPECTED_TYPES[name]
            ok = channel is not None and channel.msgtype == expected and channel.known
            if channel is not None and channel.msgtype != expected:
                self.problem(f"topic {topic} carries {channel.msgtype}, expected {expected}; not used")
            self.usable[topic] = ok  # an unknown definition was reported by the stream
        return self.usable[topic]

    def _summarise_topics(self) -> None:
        found = sorted(self.stream.channels)
        if not any(self.seen.get(name) for name in PARTS):
            if found and not any(t in self.topic_of for t in found):
                self.problem(f"a foreign bag: none of the pipeline's topics under namespace "
                             f"{self.config.namespace!r} (it holds {found[:8]}{' ...' if len(found) > 8 else ''})")
                return
        for name in (topics.EPISODE, topics.COMMAND, *PARTS):
            if not self.seen.get(name):
                self.problem(f"no usable message on {self.config.topic(name)}: episodes cannot be scored")
        if not any(self.seen.get(name) for name in LIVE_TOPICS):
            self.notes.append("no live scores recorded (scores/step, scores/episode): nothing to compare")

    # --- grouping --------------------------------------------------------------------------------
    def _episode(self, episode_id: str) -> _Episode | None:
        episode = self.open.get(episode_id)
        if episode is None and episode_id not in self.closed:
            episode = _Episode(episode_id, self.begun)
            self.order[episode_id] = self.begun
            self.begun += 1
            self.open[episode_id] = episode
            for old in list(self.open.values()):
                if old.order <= episode.order - self.config.open_episodes:
                    self._give_up(old, f"{self.config.open_episodes} newer episode(s) began first")
        return episode

    def _handle(self, name: str, msg) -> None:
        if name == topics.STEP_SCORE:
            self._live_step(msg)
            return
        if name == topics.EPISODE_SCORE:
            self._live_episode(msg)
            return
        episode = self._episode(msg.episode_id)
        if episode is None:
            return
        step = int(msg.step)
        what = f"episode {episode.episode_id} step {step} ({self.config.topic(name)})"
        if name == topics.EPISODE:
            episode.info = msg
            self._advance(episode)
            return
        if name == topics.COMMAND:  # names the controller; the applied actions come with the poses
            episode.controller = episode.controller or msg.controller
            return
        if name == topics.AGENT_POSE and step > 0:
            # The action (or -1: held) that brought the robot to this step's pose, as the simulator
            # applied it: a late command in free-running mode is in ``cmd`` but was never applied.
            episode.actions[step - 1] = action = int(msg.last_action)
            if action == STOP and (episode.first_stop is None or step - 1 < episode.first_stop):
                episode.first_stop = step - 1
        if step < episode.next_obs:
            raise BagError(f"{what}: a repeated message for a step already scored; ignored")
        else:
            part = episode.steps.setdefault(step, _Step())
            if name == topics.AUDIO:
                part.audio = _audio(msg, what)
            elif name == topics.REFINED:
                part.refined, part.stft = _spectrogram(msg, what)
            elif name == topics.GROUND_TRUTH:
                part.truth = msg
            elif name == topics.AGENT_POSE:
                part.position = _pose_xy(msg)
        self._advance(episode)

    def _advance(self, episode: _Episode) -> None:
        if episode.info is None:
            return
        last = episode.last
        while episode.next_obs <= last:
            part = episode.steps.get(episode.next_obs)
            if part is None or part.missing():
                break
            if episode.next_obs == 0:
                info = episode.info
                result = EpisodeResult(
                    episode_id=episode.episode_id, controller="", task=info.task,
                    sound_split=info.split, scene_id=info.scene_id, target_class=info.target_class,
                    shortest_path=float(part.truth.geodesic_distance))
                episode.tracker = EpisodeTracker(result, part.position)
            episode.ready.append((episode.next_obs, episode.steps.pop(episode.next_obs)))
            episode.next_obs += 1
        done = episode.next_obs > last
        if episode.ready and (done or len(episode.ready) >= self.config.batch_steps):
            if not self._score(episode):
                return
        if episode.tracker is None:
            return
        while episode.next_act in episode.actions and episode.next_act < min(episode.next_obs, last):
            episode.tracker.act(episode.next_act, episode.actions.pop(episode.next_act))
            episode.next_act += 1
        if done and episode.next_act == last:
            del self.open[episode.episode_id]
            self.closed.add(episode.episode_id)
            self.pending.append(_End(episode))
            self._apply_pending(wait=False)

    def _score(self, episode: _Episode) -> bool:
        """Scores the episode's ready steps, here or in the scoring processes; False if they cannot be
        (the episode is given up)."""
        ready, episode.ready = episode.ready, []
        try:
            groups = [ready] if len({(s.refined.shape, s.audio.shape, s.stft) for _, s in ready}) == 1 \
                else [[item] for item in ready]
            for group in groups:
                self.pending.append(self._batch(episode, group))
        except (AudioError, ConfigError) as exc:
            self._give_up(episode, f"steps {ready[0][0]}..{ready[-1][0]} cannot be scored ({exc})")
            return False
        finally:
            self._apply_pending(wait=False)
        return True

    def _batch(self, episode: _Episode, group: list[tuple[int, _Step]]) -> _Batch:
        parts = [s for _, s in group]
        truths = [p.truth for p in parts]
        rows = ([p.refined for p in parts], [p.audio for p in parts],
                [np.asarray(t.target_monaural, np.float32) for t in truths],
                [np.asarray(t.target_binaural, np.float32).reshape(2, -1) for t in truths])
        config = StftConfig(sample_rate=parts[0].stft.sample_rate, clip_samples=parts[0].audio.shape[-1])
        if self.pool is None or self._children_busy():
            magnitude, mixture, monaural, binaural = (np.stack(r) for r in rows)
            return _Batch(episode, group, score_magnitude(magnitude, mixture, StepTruth(monaural, binaural),
                                                          config=config))
        shapes = [(len(parts), *r[0].shape) for r in rows]
        block = self._block(sum(4 * math.prod(shape) for shape in shapes))
        for view, r in zip(_views(block, shapes), rows, strict=True):
            np.stack(r, out=view)
        return _Batch(episode, group, self.pool.submit(_score_shared, block.name, shapes, config), block)

    def _children_busy(self) -> bool:
        """Whether every child has a batch running and two waiting: then this one scores the next batch
        itself (at two, this one did half the scoring and the child waited on its reading)."""
        waiting = sum(1 for item in self.pending if isinstance(item, _Batch) and isinstance(item.scores, Future)
                      and not item.scores.done())
        return waiting >= 3 * self.children

    def _block(self, size: int) -> SharedMemory:
        """A free shared memory block of at least ``size`` bytes (a new one if none is)."""
        for k, block in enumerate(self.free_blocks):
            if block.size >= size:
                return self.free_blocks.pop(k)
        block = SharedMemory(create=True, size=size)
        self.blocks.append(block)
        return block

    def _apply_pending(self, *, wait: bool) -> None:
        """Takes the scores and finishes the episodes of the pending work in reading order, as far as it
        is done (all of it with ``wait``, or while more than ``in_flight`` items wait)."""
        while self.pending:
            item = self.pending[0]
            if (not wait and len(self.pending) <= self.in_flight and isinstance(item, _Batch)
                    and isinstance(item.scores, Future) and not item.scores.done()):
                return
            self.pending.popleft()
            if isinstance(item, _End):
                self._finish(item.episode)
            else:
                self._observe(item)

    def _observe(self, batch: _Batch) -> None:
        scores = batch.scores
        if isinstance(scores, Future):
            try:
                scores = scores.result()
            except (AudioError, ConfigError) as exc:
                raise _Diverged(str(exc)) from exc
            self.free_blocks.append(batch.block)
        episode = batch.episode
        for row, (step, part) in enumerate(batch.group):
            values = (float(scores.si_sdr[row]), float(scores.si_sdr_mixture_phase[row]),
                      float(scores.stft_distance[row]))
            episode.tracker.observe(step, si_sdr=values[0], si_sdr_mixture_phase=values[1],
                                    stft_distance=values[2], position=part.position,
                                    at_target=bool(part.truth.at_target))
            self._match_step((episode.episode_id, step), replayed=values)
        self.steps_scored += len(batch.group)

    def _finish(self, episode: _Episode) -> None:
        episode.tracker.result.controller = episode.controller or "unknown"
        try:
            result = episode.tracker.finish()
        except ConfigError as exc:
            if self.pool is not None:  # found later than one process finds it
                raise _Diverged(str(exc)) from exc
            self.problem(f"episode {episode.episode_id}: {exc}")
            return
        self.results.append(result)
        self._match_episode(episode.episode_id, replayed=result)

    def _give_up(self, episode: _Episode, why: str) -> None:
        self.open.pop(episode.episode_id, None)
        self.closed.add(episode.episode_id)
        pending = episode.steps.get(episode.next_obs)
        lacks = (f"; step {episode.next_obs} lacks {', '.join(self.config.topic(t) for t in pending.missing())}"
                 if pending is not None else "")
        if episode.info is None:
            lacks += f"; no {self.config.topic(topics.EPISODE)} message"
        elif episode.tracker is not None and episode.next_act < min(episode.next_obs, episode.last):
            lacks += f"; no {self.config.topic(topics.AGENT_POSE)} after step {episode.next_act}"
        total = f" of {episode.last + 1}" if episode.info is not None else ""
        self.problem(f"episode {episode.episode_id} not scored: {why} ({episode.next_obs}{total} observations "
                     f"complete{lacks})")

    # --- live scores -----------------------------------------------------------------------------
    def _live_step(self, msg) -> None:
        self._match_step((msg.episode_id, int(msg.step)), live=msg)

    def _match_step(self, key: tuple[str, int], *, live=None, replayed=None) -> None:
        if live is not None:
            self.live_steps[key] = live
        else:
            self.replayed_steps[key] = replayed
        if key in self.live_steps and key in self.replayed_steps:
            live, replayed = self.live_steps.pop(key), self.replayed_steps.pop(key)
            for metric, value in zip(METRICS, replayed, strict=True):
                self.comparison.check(key[0], key[1], metric, getattr(live, metric), value, self.config.atol)
            self.comparison.steps += 1

    def _live_episode(self, msg) -> None:
        self._match_episode(msg.episode_id, live=msg)

    def _match_episode(self, episode_id: str, *, live=None, replayed: EpisodeResult | None = None) -> None:
        if live is not None:
            self.live_episodes[episode_id] = live
        else:
            self.replayed_episodes[episode_id] = replayed
        if episode_id in self.live_episodes and episode_id in self.replayed_episodes:
            live, result = self.live_episodes.pop(episode_id), self.replayed_episodes.pop(episode_id)
            mine = {"si_sdr": result.final("si_sdr"), "si_sdr_mixture_phase": result.final("si_sdr_mixture_phase"),
                    "stft_distance": result.final("stft_distance"), "mean_si_sdr": float(np.mean(result.si_sdr)),
                    "success": float(result.success), "spl": result.spl, "path_length": result.path_length,
                    "shortest_path": result.shortest_path, "steps": float(result.steps)}
            theirs = {**{k: getattr(live, k) for k in EPISODE_FIELDS if k != "steps"}, "steps": live.step}
            for metric in EPISODE_FIELDS:
                atol = 0.0 if metric in ("success", "steps") else self.config.atol
                self.comparison.check(episode_id, None, f"episode_{metric}", float(theirs[metric]), mine[metric], atol)
            self.comparison.episodes += 1


def replay_bag(path: str | Path, *, config: ReplayConfig = ReplayConfig()) -> BagReplay:
    """Score one recorded run from its bag; raises BagError only if nothing in it can be read."""
    try:
        return _Replayer(Path(path), config).run()
    except _Diverged:
        return _Replayer(Path(path), replace(config, score_processes=1)).run()


def _replay_or_error(path: Path, config: ReplayConfig) -> BagReplay | BagError:
    try:
        return replay_bag(path, config=config)
    except BagError as exc:  # returned, not raised: the other bags' replays go on, in order
        return exc


def available_cores() -> int:
    """The CPUs this process may run on (its affinity mask, which containers and taskset narrow)."""
    return len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count() or 1


def replay_bags(paths: Iterable[str | Path], *, config: ReplayConfig = ReplayConfig(), workers: int = 1
                ) -> Iterator[BagReplay | BagError]:
    """:func:`replay_bag` of each bag, yielded in the order given: its BagReplay, or the BagError of a bag
    nothing of which can be read, on ``workers`` processes: with at least that many bags, that many bags
    at once, each in a child process; with fewer, one bag after another, each read here and its steps
    scored by ``workers`` processes. The same replays as one worker, in the same order."""
    if workers < 1:
        raise ConfigError(f"workers must be >= 1, got {workers}")
    return _replays_in_order([Path(p) for p in paths], config, workers)


def _replays_in_order(paths: list[Path], config: ReplayConfig, workers: int) -> Iterator[BagReplay | BagError]:
    if workers == 1 or len(paths) < workers:
        config = config if workers == 1 else replace(config, score_processes=workers)
        yield from (_replay_or_error(p, config) for p in paths)
        return
    # With fork, the pool forks all its children before it starts its own threads.
    pool = _scoring_pool(workers)
    with pool:
        yield from pool.map(_replay_or_error, paths, [config] * len(paths))


# --- reports -------------------------------------------------------------------------------------
def _subset_plots(results: Sequence[EpisodeResult], out: Path) -> dict[str, Path]:
    """SI-SDR vs step per controller, one plot per task x sound split (near/far, heard/unheard)."""
    plots = {}
    for task, split in sorted({(r.task, r.sound_split) for r in results}):
        members = [r for r in results if (r.task, r.sound_split) == (task, split)]
        plots[f"plot_{task}_{split}"] = plot_si_sdr_vs_step(
            members, out / f"si_sdr_vs_step_{task}_{split}.png", title=f"{task}, {split} sounds")
    return plots


def write_replay(replays: Iterable[BagReplay], out_dir: str | Path, *, atol: float, plot: bool = True
                 ) -> dict[str, Path]:
    """The results tables and plots of every replayed bag, plus comparison.{md,csv} (replayed vs live)
    and the problems found; returns the paths by kind."""
    replays = list(replays)
    out = Path(out_dir)
    results = [r for replay in replays for r in replay.results]
    bags = [{"bag": str(r.bag), "episodes": len(r.results), "steps_scored": r.steps_scored,
             "messages": r.stats.messages, "chunks": r.stats.chunks, "bytes": r.stats.bytes,
             "complete": r.stats.complete, "problems": [str(p) for p in r.problems], "notes": r.notes,
             "compared_steps": r.comparison.steps, "compared_episodes": r.comparison.episodes,
             "max_diff": r.comparison.max_diff, "mismatches": len(r.comparison.mismatches),
             "live_only": r.comparison.live_only, "replayed_only": r.comparison.replayed_only}
            for r in replays]
    paths = write_results(results, out, title="Replayed scores", plot=plot and bool(results),
                          meta={"tool": "m2h-eval", "atol": atol, "bags": bags})
    if plot and results:
        paths.update(_subset_plots(results, out))
    paths["comparison_csv"] = out / "comparison.csv"
    with paths["comparison_csv"].open("w", newline="") as stream:
        writer = csv.writer(stream)
        writer.writerow(["bag", "episode_id", "step", "metric", "live", "replayed", "difference"])
        for replay in replays:
            for m in replay.comparison.mismatches:
                writer.writerow([replay.bag, m.episode_id, "" if m.step is None else m.step, m.metric,
                                 repr(m.live), repr(m.replayed), repr(m.replayed - m.live)])
    lines = ["# Replayed vs live scores", "",
             f"Tolerance: |replayed - live| <= {atol:g} (dB for SI-SDR; success and step count exactly).", "",
             "| bag | episodes | steps scored | steps compared | episodes compared | mismatches | "
             "max diff SI-SDR | max diff SI-SDR (mix) | max diff STFT | problems |", "|" + "---|" * 10]
    for b in bags:
        d = b["max_diff"]
        lines.append(f"| {b['bag']} | {b['episodes']} | {b['steps_scored']} | {b['compared_steps']} | "
                     f"{b['compared_episodes']} | {b['mismatches']} | "
                     + " | ".join(f"{d[m]:.2e}" if m in d else "-" for m in METRICS)
                     + f" | {len(b['problems'])} |")
    for b in bags:
        for text in b["problems"] + b["notes"]:
            lines.append(f"\n- {text}")
    paths["comparison"] = out / "comparison.md"
    paths["comparison"].write_text("\n".join(lines) + "\n")
    return paths
