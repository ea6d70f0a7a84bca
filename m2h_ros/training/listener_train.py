"""Training the listener output (``models/listener.py``) for what a listener gets: step-0 examples
rendered from episodes (the binaural mixture and the target's early image at each ear, the reference
``listener_eval`` scores against), and a loss on the waveform the robot plays, phase included:
the negative SI-SDR at each ear plus at the ear mean.

The trainer checkpoints every ``checkpoint_every`` steps (model, optimiser, step, random state; written
whole or not at all) and resumes from that file when it exists, so a killed run goes on where it stopped.
BatchNorm keeps f^B's running statistics (eval mode) while every weight trains: small batches would
otherwise move statistics the copied weights were tuned to.
"""

from __future__ import annotations

import math
import os
import tempfile
import time
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch
from tqdm import tqdm

from m2h_ros.core.audio.stft import StftConfig
from m2h_ros.core.sounds.library import TARGET_CATEGORIES, SoundLibrary
from m2h_ros.core.world.env import BatchEnv, EnvConfig
from m2h_ros.core.world.episodes import MOVE_FORWARD, TURN_LEFT, TURN_RIGHT, Episode
from m2h_ros.errors import ConfigError
from m2h_ros.models.listener import Listener
from m2h_ros.training.listener_eval import early_images
from m2h_ros.training.passive_eval import step_zero_batches
from m2h_ros.training.teacher import approach_action


@dataclass(frozen=True)
class ListenerExamples:
    """Step-0 training examples: ``mixture`` and ``early`` (E, 2, N) float16 (the early image at each
    ear), ``target_class`` (E,) indices into ``TARGET_CATEGORIES``."""

    mixture: np.ndarray
    early: np.ndarray
    target_class: np.ndarray

    def __len__(self) -> int:
        return len(self.target_class)

    def save(self, path: Path) -> None:
        """Atomically (temporary file + rename)."""
        path.parent.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(prefix=path.name, suffix=".tmp.npz", dir=path.parent)
        os.close(fd)
        try:
            np.savez(tmp, mixture=self.mixture, early=self.early, target_class=self.target_class)
            os.replace(tmp, path)
        finally:
            if os.path.exists(tmp):
                os.unlink(tmp)

    @classmethod
    def load(cls, path: Path) -> ListenerExamples:
        with np.load(path) as data:
            return cls(data["mixture"], data["early"], data["target_class"])

    @classmethod
    def concatenate(cls, parts: Sequence[ListenerExamples]) -> ListenerExamples:
        return cls(*(np.concatenate([getattr(p, name) for p in parts])
                     for name in ("mixture", "early", "target_class")))


def render_examples(episodes: Sequence[Episode], library: SoundLibrary, *, env_config: EnvConfig,
                    poses: int = 1, approach: float = 0.0, seed: int = 0, n_envs: int = 16,
                    progress: bool = True) -> ListenerExamples:
    """The mixture and the target's early image at each ear of every episode at ``poses`` poses: its
    start, then after each of ``poses - 1`` moves (forward, left, right; never Stop), each a step along
    a shortest path to the target with probability ``approach``, else random. The same sources and
    clips heard from elsewhere: more rooms' worth of examples from the RIRs of one episode's sources;
    with ``approach``, also from where a robot that moves to hear better ends up, near the target."""
    episodes = list(episodes)
    if not episodes:
        raise ConfigError("render_examples needs at least one episode")
    if poses < 1 or any(poses > episode.max_steps for episode in episodes):
        raise ConfigError(f"poses={poses} must be in [1, the episodes' step count]")
    if not 0.0 <= approach <= 1.0:
        raise ConfigError(f"approach={approach!r} must be a probability in [0, 1]")
    rng = np.random.default_rng(seed)
    env = BatchEnv(episodes, library, n_envs=min(n_envs, len(episodes)), config=env_config, autoreset=False)
    mixtures, earlies, classes = [], [], []
    try:
        for rows, keep, obs, info in step_zero_batches(env, episodes, desc="listener examples", progress=progress):
            for pose in range(poses):
                if pose:
                    obs, _, _, _, info = env.step(_moves(env, obs, approach, rng))
                mixtures.append(obs["audio"][keep].astype(np.float16))
                earlies.append(early_images(info["target_monaural"][keep], env.target_rirs(range(len(rows))),
                                            info["target_delay"][keep],
                                            sample_rate=env_config.stft.sample_rate).astype(np.float16))
                classes.append(np.asarray(obs["target_class"][keep], np.int64))
    finally:
        env.close()
    return ListenerExamples(np.concatenate(mixtures), np.concatenate(earlies), np.concatenate(classes))


def _moves(env: BatchEnv, obs: dict, approach: float, rng: np.random.Generator) -> np.ndarray:
    """Each slot's next move: random (forward, left, right), or with probability ``approach`` the
    shortest path's toward its target (a turn where the slot is on the target)."""
    moves = rng.integers(MOVE_FORWARD, TURN_RIGHT + 1, env.n_envs)
    if not approach:   # no further draw: random walks stay as they were
        return moves
    for slot in np.flatnonzero(rng.random(env.n_envs) < approach):
        episode = env.current_episodes[slot]
        toward = approach_action(episode.scene().grid, int(obs["node"][slot]), int(obs["heading"][slot]),
                                 episode.target_node)
        moves[slot] = TURN_LEFT if toward is None else toward
    return moves


@dataclass(frozen=True)
class ListenerTrainConfig:
    steps: int = 3000
    batch_size: int = 16
    learning_rate: float = 3e-4
    validation_fraction: float = 0.05
    checkpoint_every: int = 100
    seed: int = 0

    def __post_init__(self) -> None:
        for name in ("steps", "batch_size", "checkpoint_every"):
            value = getattr(self, name)
            if not isinstance(value, int) or isinstance(value, bool) or value < 1:
                raise ConfigError(f"ListenerTrainConfig.{name} must be a positive int, got {value!r}")
        if not 0 < self.learning_rate < 1:
            raise ConfigError(f"ListenerTrainConfig.learning_rate must be in (0, 1), got {self.learning_rate!r}")
        if not 0 <= self.validation_fraction < 0.5:
            raise ConfigError("ListenerTrainConfig.validation_fraction must be in [0, 0.5), got "
                              f"{self.validation_fraction!r}")


def si_sdr_torch(estimate: torch.Tensor, reference: torch.Tensor, eps: float = 1e-8) -> torch.Tensor:
    """SI-SDR in dB over the last axis (zero-mean, as ``core.audio.metrics.si_sdr``), differentiable."""
    estimate = estimate - estimate.mean(dim=-1, keepdim=True)
    reference = reference - reference.mean(dim=-1, keepdim=True)
    scale = (estimate * reference).sum(-1, keepdim=True) / (reference.square().sum(-1, keepdim=True) + eps)
    target = scale * reference
    return 10 * torch.log10(target.square().sum(-1) / ((estimate - target).square().sum(-1) + eps) + eps)


class WaveformTransform:
    """torch STFT / inverse with ``core.audio.stft``'s settings, so training sees what inference computes."""

    def __init__(self, config: StftConfig) -> None:
        if not (config.center and config.pad_mode == "reflect" and config.win_length == config.n_fft):
            raise ConfigError("the listener trains with centred, reflect-padded frames of window = n_fft")
        self.config = config
        self.window = torch.hann_window(config.win_length)

    def stft(self, waveform: torch.Tensor) -> torch.Tensor:
        lead = waveform.shape[:-1]
        spec = torch.stft(waveform.reshape(-1, waveform.shape[-1]), n_fft=self.config.n_fft,
                          hop_length=self.config.hop_length, win_length=self.config.win_length, window=self.window,
                          center=True, pad_mode="reflect", return_complex=True)
        return spec.reshape(*lead, *spec.shape[-2:])

    def istft(self, spec: torch.Tensor, length: int) -> torch.Tensor:
        lead = spec.shape[:-2]
        wave = torch.istft(spec.reshape(-1, *spec.shape[-2:]), n_fft=self.config.n_fft,
                           hop_length=self.config.hop_length, win_length=self.config.win_length, window=self.window,
                           center=True, length=length)
        return wave.reshape(*lead, length)


def listener_loss(estimate: torch.Tensor, early: torch.Tensor) -> torch.Tensor:
    """Negative SI-SDR (dB) of (B, 2, N) waveforms against the early image: each ear and the ear mean."""
    per_ear = si_sdr_torch(estimate, early).mean(dim=1)
    ear_mean = si_sdr_torch(estimate.mean(dim=1), early.mean(dim=1))
    return -(per_ear + ear_mean).mean() / 2


def _save_state(path: Path, state: dict) -> None:
    fd, tmp = tempfile.mkstemp(prefix=path.name, suffix=".tmp", dir=path.parent)
    os.close(fd)
    try:
        torch.save(state, tmp)
        os.replace(tmp, path)
    finally:
        if os.path.exists(tmp):
            os.unlink(tmp)


def evaluate_examples(listener: Listener, examples: ListenerExamples, class_map: np.ndarray,
                      transform: WaveformTransform, *, batch_size: int = 32) -> float:
    """Mean ear-mean SI-SDR (dB) of the listener's output against the early image."""
    scores = []
    listener.eval()
    with torch.no_grad():
        for start in range(0, len(examples), batch_size):
            part = slice(start, start + batch_size)
            mixture = torch.from_numpy(examples.mixture[part].astype(np.float32))
            early = torch.from_numpy(examples.early[part].astype(np.float32))
            classes = torch.from_numpy(class_map[examples.target_class[part]])
            out = transform.istft(listener(transform.stft(mixture), classes), mixture.shape[-1])
            scores.append(si_sdr_torch(out.mean(dim=1), early.mean(dim=1)))
    return float(torch.cat(scores).mean())


def train_listener(listener: Listener, examples: ListenerExamples, *, class_map: np.ndarray, stft_config: StftConfig,
                   config: ListenerTrainConfig, state_path: Path, log=print, progress: bool = True) -> dict:
    """Train ``listener`` in place; returns a summary (steps, validation SI-SDR before and after, seconds).
    ``class_map`` turns ``TARGET_CATEGORIES`` indices into the model's class indices."""
    if len(class_map) != len(TARGET_CATEGORIES):
        raise ConfigError(f"class_map needs one entry per target category {TARGET_CATEGORIES}")
    order = np.random.default_rng(config.seed).permutation(len(examples))
    n_val = math.ceil(config.validation_fraction * len(examples)) if config.validation_fraction else 0
    take = lambda idx: ListenerExamples(examples.mixture[idx], examples.early[idx], examples.target_class[idx])  # noqa: E731
    validation, train = take(np.sort(order[:n_val])), take(np.sort(order[n_val:]))
    if len(train) < config.batch_size:
        raise ConfigError(f"{len(train)} training examples, fewer than one batch of {config.batch_size}")
    transform = WaveformTransform(stft_config)
    optimiser = torch.optim.Adam(listener.parameters(), lr=config.learning_rate)
    rng = np.random.default_rng(config.seed + 1)
    step, history, started_at = 0, [], time.perf_counter()
    if state_path.exists():
        state = torch.load(state_path, weights_only=False)
        listener.load_state_dict(state["model"])
        optimiser.load_state_dict(state["optimiser"])
        rng.bit_generator.state = state["rng"]
        step, history = state["step"], state["history"]
        log(f"resumed at step {step} from {state_path}")
    elif n_val:
        history.append({"step": 0, "validation_si_sdr": evaluate_examples(listener, validation, class_map, transform)})
        log(f"step 0: validation SI-SDR {history[-1]['validation_si_sdr']:.2f} dB")
    first = step  # cosine decay over the whole run, wherever this part of it starts
    schedule = torch.optim.lr_scheduler.LambdaLR(
        optimiser, lambda k: 0.5 * (1 + math.cos(math.pi * min(k + first, config.steps) / config.steps)))
    bar = tqdm(total=config.steps, initial=step, desc="listener", unit="step", disable=not progress)
    running = []
    while step < config.steps:
        listener.train()
        for module in listener.modules():
            if isinstance(module, torch.nn.BatchNorm2d):
                module.eval()
        idx = rng.choice(len(train), size=config.batch_size, replace=False)
        mixture = torch.from_numpy(train.mixture[idx].astype(np.float32))
        early = torch.from_numpy(train.early[idx].astype(np.float32))
        swap = torch.from_numpy(rng.random(config.batch_size) < 0.5)  # mirrored heads: left and right swapped
        mixture = torch.where(swap[:, None, None], mixture.flip(1), mixture)
        early = torch.where(swap[:, None, None], early.flip(1), early)
        classes = torch.from_numpy(class_map[train.target_class[idx]])
        estimate = transform.istft(listener(transform.stft(mixture), classes), mixture.shape[-1])
        loss = listener_loss(estimate, early)
        optimiser.zero_grad()
        loss.backward()
        torch.nn.utils.clip_grad_norm_(listener.parameters(), 5.0)
        optimiser.step()
        schedule.step()
        step += 1
        running.append(float(loss.detach()))
        bar.update(1)
        if step % config.checkpoint_every == 0 or step == config.steps:
            entry = {"step": step, "train_loss": float(np.mean(running))}
            if n_val:
                entry["validation_si_sdr"] = evaluate_examples(listener, validation, class_map, transform)
            history.append(entry)
            running = []
            _save_state(state_path, {"model": listener.state_dict(), "optimiser": optimiser.state_dict(),
                                     "rng": rng.bit_generator.state, "step": step, "history": history})
            log(" ".join(f"{k} {v:.3f}" if isinstance(v, float) else f"{k} {v}" for k, v in entry.items()))
    bar.close()
    listener.eval()
    return {"steps": step, "history": history, "seconds_this_run": round(time.perf_counter() - started_at, 1)}
