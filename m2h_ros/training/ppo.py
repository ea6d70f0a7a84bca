"""PPO and DD-PPO training of the learned controllers, in-process on ``BatchEnv``; one readable loop.

    python scripts/train_policy.py --kind quality|navigation|approach|novelty|av_navigator [--updates N] [--out DIR]
    torchrun --nproc_per_node 2 scripts/train_policy.py ...       # DD-PPO: 2 workers, gradients all-reduced

One update (CleanRL-style, hyperparameters in :class:`PPOConfig`):

1. Rollout: ``n_steps`` steps of ``n_envs`` slots. Per step the passive separator runs batched over
   the slots (``SeparatorRunner``: f^B, f^M frozen, f^R with one memory per slot), the policy sees
   exactly what a controller sees (``agents.rollout.controller_observation`` -> ``policy_inputs``)
   and samples an action; the env steps (same-step auto-reset; the terminal observation is separated
   too, continuing its episode's memory, so the last reward sees the episode's final estimate).
2. Rewards by kind: ``quality`` (Move2Hear pi^Q) the improvement of the refined estimate's quality
   measure (``quality_reward``), plus ``final_weight`` x the measure at the episode's last step (the
   original code's formulation; it adds that term one step early because Habitat's auto-reset hides
   the last observation, here it lands on the last step itself), plus ``navigation_coef`` x the env's
   navigation reward (0.25 per metre of geodesic distance gained, -0.01 a step: a mixed reward that pays
   for approaching the target beside hearing it better). ``nmse`` (default, the original's):
   NMSE_t - NMSE_{t+1} against the ground-truth monaural magnitude (NMSE = mean squared error / mean
   squared target), -10 x NMSE last; ``snr``: SNR_{t+1} - SNR_t in dB (SNR = -10 log10 NMSE),
   +10 x SNR dB last; ``si_sdr``: SI-SDR_{t+1} - SI-SDR_t in dB of the waveform rebuilt with the
   ground-truth monaural phase, as the evaluation scores it, +10 x SI-SDR dB last. ``navigation``
   (pi^N + Stop, AV Navigator) the env's reward (+10 for Stop at the target, +-0.25 per metre of
   geodesic distance, -0.01 per step); ``approach`` (the original's far-target policy of the
   composite: no Stop, 80-step episodes) the env's reward with the original's settings for it, +1 per
   metre of geodesic distance gained and nothing else (``KindSpec.env_reward``); ``novelty`` 1 / sqrt(n)
   with n the visits (this one included) of the node the step arrives at in this episode.
3. GAE(gamma, lambda) advantages, normalised (over all workers with DD-PPO); an episode end is
   terminal (no bootstrap), as in the original.
4. ``ppo_epochs`` passes of ``n_minibatches`` minibatches (whole slot sequences, the GRU re-run from
   the rollout's first hidden state): clipped surrogate x action_coef + clipped value loss x
   value_coef - entropy x entropy_coef; Adam, gradient norm clipped; lr and clip decay linearly.
   With ``teacher_coef`` > 0 (kickstarting, ``training.teacher``) the loss adds that weight, decaying
   with lr, x the cross-entropy from the approach teacher's action distribution at each visited state.
   With ``location_coef`` > 0 (``training.location``) it adds that weight x the Huber loss of a
   training-only linear head on the GRU's output that predicts the target's position relative to the
   robot (an auxiliary task: the GRU learns to gather where the target is over steps and turns).
   ``init_policy`` starts the weights from a checkpoint instead of at random (``models.policy.warm_start``:
   e.g. pi^Q from pi^N, whose actor rows are matched by action; the optimiser starts fresh).
5. f^R (``train_refiner``, default for ``quality`` only): ``refiner_epochs`` passes of L1 between
   f^R(f^M estimate, stored memory) and the ground-truth magnitude, Adam ``refiner_lr`` (the
   original's lr_sep 5e-4), as the original's ``update_sep`` (ppo_epoch passes: 4); f^R's BatchNorm keeps its pretrained
   statistics (eval mode) so acting and training compute the same function. The trained separator
   is written beside the policy (``separator.pt``): pair them at evaluation.
   ``frozen_policy`` makes a run an f^R-only stage: no PPO update (the policy acts as loaded by
   ``init_policy``), and slots ``[0, teacher_slots)`` act with the approach teacher instead (its
   walk to the target's node, then turns on it), so f^R also learns from rollouts that hold still
   near the target, which pi^Q's alone rarely do.

DD-PPO (``torchrun``; gloo on CPU, nccl on CUDA): every worker has its own environments (env seed +
rank: its own episode order) and sampling stream; weights start equal (broadcast from rank 0);
gradients of the policy and of f^R are all-reduced (averaged) before clipping and the Adam step, so
all workers keep identical weights. (The original's straggler preemption is not needed here: all
workers step the same number of slots per update.)

Outputs in ``out_dir``: ``policy.pt`` (self-describing, kind ``m2h_policy``), ``separator.pt``
(when f^R trains), ``log.csv`` (one row per update), ``curve.png``, ``config.json``, and
``resume.pt`` (``resume.rank<r>.pt`` per DD-PPO worker): everything the loop holds (weights,
optimisers, random streams, env slots, the current observation, separator memory, GRU state), so a
run that stops at a checkpoint and restarts continues with exactly the numbers it would have had.
"""

from __future__ import annotations

import csv
import dataclasses
import json
import math
import os
import time
from collections import deque
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

# Spinning OpenMP workers collapse torch's speed on a shared machine (see pretrain_separator).
os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")

import numpy as np  # noqa: E402
import torch  # noqa: E402
import torch.distributed as dist  # noqa: E402
import torch.nn.functional as F  # noqa: E402
from tqdm import tqdm  # noqa: E402

from m2h_ros.agents.rollout import controller_observation  # noqa: E402
from m2h_ros.core.audio.stft import to_slices  # noqa: E402
from m2h_ros.core.sounds.library import SoundLibrary  # noqa: E402
from m2h_ros.core.world.env import BatchEnv  # noqa: E402
from m2h_ros.core.world.episodes import episodes_for  # noqa: E402
from m2h_ros.errors import CheckpointError, ConfigError  # noqa: E402
from m2h_ros.models.device import resolve_device  # noqa: E402
from m2h_ros.models.checkpoint import DEFAULT_SEPARATOR_CHECKPOINT, load_separator, save_separator  # noqa: E402
from m2h_ros.models.policy import (PolicyInputs, PolicyNet, policy_input_buffers,  # noqa: E402
                                   load_policy, policy_inputs, save_policy, sliced_policy_inputs, warm_start)
from m2h_ros.models.runner import SeparationStep, SeparatorRunner  # noqa: E402
from m2h_ros.machine import machine_description  # noqa: E402
from m2h_ros.paths import repo_relative  # noqa: E402
from m2h_ros.training.rewards import PendingQuality, QualityTracker  # noqa: E402
from m2h_ros.training.distributed import all_reduce_mean, all_reduce_sum, init_distributed  # noqa: E402
from m2h_ros.training.plots import save_panels, two_panels  # noqa: E402
from m2h_ros.training.ppo_config import PPOConfig  # noqa: E402
from m2h_ros.training.location import location_head, location_loss, target_offsets  # noqa: E402
from m2h_ros.training.teacher import teacher_probabilities  # noqa: E402


WINDOWED = ("return", "final_nmse", "final_quality", "success")  # per-episode values, logged as 50-episode means
POLICY_LOSSES = ("value_loss", "action_loss", "entropy", "teacher_ce", "location_loss", "location_error_m")
TIMED_PARTS = ("sim", "separator", "act", "update", "refiner")  # log columns <part>_share
SEPARATOR_POSE_CACHE = 32  # poses per slot whose f^B / f^M outputs the rollout keeps (BatchEnv's pose_cache)


@dataclass
class TrainResult:
    net: PolicyNet
    out_dir: Path
    history: list[dict[str, float]]
    checkpoint: Path


# --------------------------------------------------------------------------- helpers


def gae(rewards: torch.Tensor, values: torch.Tensor, dones: torch.Tensor, next_value: torch.Tensor, *,
        gamma: float, lam: float) -> torch.Tensor:
    """Generalised advantage estimates (T, N); ``dones[t]``: the episode ended with action t."""
    advantages = torch.zeros_like(rewards)
    last = torch.zeros_like(next_value)
    for t in reversed(range(rewards.shape[0])):
        nonterminal = 1.0 - dones[t].float()
        following = next_value if t == rewards.shape[0] - 1 else values[t + 1]
        delta = rewards[t] + gamma * following * nonterminal - values[t]
        last = delta + gamma * lam * nonterminal * last
        advantages[t] = last
    return advantages


def _sliced(magnitude: np.ndarray | torch.Tensor, n_slices: int) -> torch.Tensor:
    """(B, F, T) monaural magnitude, or its sliced tensor -> a copy (B, S, F / S, T) (the caller's array
    changes in place), in channels_last: f^R's convolutions train ~12% faster in it."""
    if isinstance(magnitude, np.ndarray):
        magnitude = torch.from_numpy(to_slices(magnitude[:, None], n_slices=n_slices))
    return magnitude.cpu().clone(memory_format=torch.channels_last)


def _poses(obs: dict, rows: np.ndarray | None = None) -> list[tuple[int, int]]:
    """(node, heading) of each slot (``rows``): the separator's cache keys (one clip per pose and episode)."""
    nodes, headings = (obs["node"], obs["heading"]) if rows is None else (obs["node"][rows], obs["heading"][rows])
    return list(zip(nodes.tolist(), headings.tolist(), strict=True))


def _to_tensors(values: dict[str, np.ndarray]) -> dict[str, torch.Tensor]:
    return {key: torch.from_numpy(np.ascontiguousarray(value)) for key, value in values.items()}


def _to_arrays(values: dict[str, torch.Tensor]) -> dict[str, np.ndarray]:
    return {key: value.numpy().copy() for key, value in values.items()}


def _with_defaults(defaults: dict[str, Any], given: dict[str, Any]) -> dict[str, Any]:
    """``given`` with the keys it lacks taken from ``defaults``, in nested dicts too."""
    merged = {**defaults, **given}
    for key, value in defaults.items():
        if isinstance(value, dict) and isinstance(given.get(key), dict):
            merged[key] = _with_defaults(value, given[key])
    return merged


def plot_curve(path: Path, history: list[dict[str, float]], *, kind: str) -> Path:
    """Training curve: episode return (and pi^Q's final NMSE) and the losses vs environment steps."""
    steps = [h["env_steps"] for h in history]
    fig, (left, right) = two_panels()
    left.plot(steps, [h["return_window"] for h in history], "C0-", label="episode return (last 50)")
    if kind == "quality":
        twin = left.twinx()
        twin.plot(steps, [h["final_nmse_window"] for h in history], "C3-", label="final NMSE (last 50)")
        twin.set_ylabel("final NMSE")
        twin.legend(loc="lower right", fontsize=8)
    left.set(title=f"PPO {kind}", xlabel="environment steps", ylabel="return")
    for key, style in (("value_loss", "C1-"), ("action_loss", "C2-"), ("entropy", "C4-"), ("refiner_l1", "C5-"),
                       ("teacher_ce", "C6-"), ("location_loss", "C7-")):
        right.plot(steps, [h[key] for h in history], style, label=key.replace("_", " "))
    right.set(title="losses", xlabel="environment steps")
    return save_panels(fig, (left, right), path)


# --------------------------------------------------------------------------- the trainer


@dataclass
class _Rollout:
    """One update's experience of N slots over T steps (time-major)."""

    inputs: PolicyInputs  # (T, N, ...): the trainer's buffers, which the next rollout overwrites
    actions: list[torch.Tensor] = field(default_factory=list)  # network action indices
    log_probs: list[torch.Tensor] = field(default_factory=list)
    values: list[torch.Tensor] = field(default_factory=list)
    rewards: list[torch.Tensor] = field(default_factory=list)
    starts: list[torch.Tensor] = field(default_factory=list)  # obs t is its episode's first
    dones: list[torch.Tensor] = field(default_factory=list)  # the episode ended with action t
    monaural: list[torch.Tensor] = field(default_factory=list)  # f^R's inputs and target, sliced
    memory: list[torch.Tensor] = field(default_factory=list)
    target: list[torch.Tensor] = field(default_factory=list)
    teacher: list[torch.Tensor] = field(default_factory=list)  # (N, outputs): the approach teacher's distribution
    offsets: list[torch.Tensor] = field(default_factory=list)  # (N, 2): the target's (forward, left) metres


@dataclass(frozen=True)
class _StepReward:
    """A step's reward, known (``reward``) or being computed (``quality``), and its episode ends."""

    ended: np.ndarray  # slots whose episode the step ended
    success: np.ndarray | None  # (N,) with the step's final_info when an episode ended
    reward: np.ndarray | None = None  # quality: the part added to the quality reward (navigation_coef), if any
    quality: PendingQuality | None = None


class PPOTrainer:
    """The state of one training worker and its loop (``run``); see the module docstring."""

    def __init__(self, config: PPOConfig, library: SoundLibrary, *, out_dir: Path,
                 rir_cache_dir: Path | None = None, progress: bool = True, command: str | None = None) -> None:
        self.config, self.out_dir, self.command = config, Path(out_dir), command or "PPOTrainer"
        self.device = resolve_device(config.device, field="PPOConfig.device")
        self.rank, self.world = init_distributed(self.device)
        self.progress = progress and self.rank == 0
        torch.set_num_threads(config.threads)
        torch.manual_seed(config.seed)
        self.policy_config = config.policy_config()
        self.net = PolicyNet(self.policy_config).to(self.device)
        if config.init_policy:
            warm_start(self.net, load_policy(config.init_policy, map_location=self.device))
        self.optimizer = torch.optim.Adam(self.net.parameters(), lr=config.lr, eps=config.adam_eps)
        # Made only when used: its initialisation draws from torch's generator.
        self.location_head = location_head(self.policy_config.hidden).to(self.device) if config.location_coef else None
        if self.location_head is not None:
            self.optimizer.add_param_group({"params": list(self.location_head.parameters())})
        self.loaded = load_separator(config.separator or DEFAULT_SEPARATOR_CHECKPOINT, map_location=self.device)
        self.policy_config.check_stft(self.loaded.stft)
        if self.loaded.stft != config.env.stft:
            raise ConfigError("the separator's STFT settings differ from the environment's")
        self.separator = self.loaded.separator
        self.refiner_optimizer = torch.optim.Adam(self.separator.refiner.parameters(), lr=config.refiner_lr,
                                                  eps=config.adam_eps)
        if self.world > 1:
            head = [] if self.location_head is None else list(self.location_head.state_dict().values())
            for tensor in [*self.net.state_dict().values(), *self.separator.refiner.state_dict().values(), *head]:
                dist.broadcast(tensor, 0)
        self.episodes = episodes_for(config.episode_config(), library)
        env_config = dataclasses.replace(config.env, seed=config.env.seed + self.rank)
        self.env = BatchEnv(self.episodes, library, n_envs=config.n_envs, config=env_config,
                            rir_cache_dir=rir_cache_dir, threads=config.threads)
        # Microphone noise makes every observation new: nothing to reuse then.
        self.runner = SeparatorRunner(self.loaded, config.n_envs,
                                      pose_cache=0 if config.env.mic_noise > 0 else SEPARATOR_POSE_CACHE)
        self.quality = QualityTracker(config.quality_reward, final_weight=config.final_weight, config=self.loaded.stft,
                                      threaded=config.spec.reward == "quality")
        self.actions = torch.from_numpy(self.policy_config.env_actions())
        self.rollout_inputs = policy_input_buffers(self.policy_config, steps=config.n_steps, slots=config.n_envs)
        self.generator = torch.Generator().manual_seed(config.seed * 1_000_003 + self.rank)
        self.rng = np.random.default_rng([config.seed, self.rank])
        self.update, self.env_steps, self.history = 0, 0, []
        self.windows = {key: deque(maxlen=50) for key in WINDOWED}
        self.times = np.zeros(5)  # sim, separator, acting, policy update, f^R update (seconds, this worker)
        self.wall_before = 0.0  # seconds spent in earlier sessions of this run
        self.resume_path = self.out_dir / ("resume.pt" if self.world == 1 else f"resume.rank{self.rank}.pt")

    # ------------------------------------------------------------------ episode state
    def _begin(self) -> None:
        """Fresh start: reset every slot and separate the first observations."""
        n = self.config.n_envs
        self.obs, info = self.env.reset()
        self.starts = np.ones(n, bool)
        self.hidden = self.net.initial_hidden(n)
        self.returns, self.lengths = np.zeros(n), np.zeros(n, np.int64)
        self.visits = np.zeros((n, self.env.max_nodes), np.int64)
        self.visits[np.arange(n), self.obs["node"]] = 1
        self.last_classes = self._classes()
        self.separation = self.runner.step(self.obs["audio"], self.last_classes, np.ones(n, bool),
                                           keys=_poses(self.obs))
        # The memory each slot's current estimate was refined with, which f^R trains on (all slots
        # start afresh here); kept only while f^R trains.
        self.previous_memory = torch.zeros_like(self.runner.memory) if self.refining else None
        self.quality.start(info["target_monaural"], self.separation.refined)

    def _classes(self) -> np.ndarray:
        return self.runner.class_indices([e.target_category for e in self.env.current_episodes])

    def _inputs(self, obs: dict, separation: SeparationStep, out: PolicyInputs | None = None) -> PolicyInputs:
        if self.policy_config.inputs == "separation" and separation.sliced is not None:
            # policy_inputs' numbers from the separator's own tensors (a restored step has only the arrays)
            binaural, monaural, refined = (t.cpu() for t in separation.sliced)
            return sliced_policy_inputs(self.policy_config, binaural=binaural, monaural=monaural, refined=refined,
                                        rgb=obs.get("rgb"), out=out)
        seen = controller_observation(obs, separation, uses_separator=self.policy_config.inputs == "separation")
        return policy_inputs(self.policy_config, separated_binaural=seen.separated_binaural, monaural=seen.monaural,
                             refined=seen.refined, audio=seen.audio, target_class=obs["target_class"], rgb=seen.rgb,
                             stft_config=self.loaded.stft, out=out)

    # ------------------------------------------------------------------ rollout
    def _collect(self) -> tuple[_Rollout, torch.Tensor, list[dict[str, float]]]:
        """n_steps steps of every slot; returns the rollout, the bootstrap value and finished episodes."""
        cfg, s = self.config, self.loaded.config.n_freq_slices
        rollout, finished = _Rollout(self.rollout_inputs), []
        self.hidden_start = self.hidden.clone()
        pending: _StepReward | None = None  # the last step's reward: settled after the next step's separation
        for t in range(cfg.n_steps):
            tick = time.perf_counter()
            inputs = self._inputs(self.obs, self.separation, out=rollout.inputs.index(t))  # written in place: no stack
            starts = torch.from_numpy(self.starts.copy())
            with torch.no_grad():
                out = self.net.step(inputs.to(self.device), self.hidden, starts.to(self.device))
                probs = torch.softmax(out.logits, dim=-1).cpu()
                action = torch.multinomial(probs, 1, generator=self.generator)[:, 0]
                log_prob = torch.log(probs.gather(1, action[:, None])[:, 0])
            self.hidden = out.hidden
            if cfg.teacher_slots:
                self._teacher_acts(action)
            rollout.actions.append(action)
            rollout.log_probs.append(log_prob)
            rollout.values.append(out.value.cpu())
            rollout.starts.append(starts)
            if cfg.teacher_coef:
                rollout.teacher.append(torch.from_numpy(teacher_probabilities(
                    self.env.current_episodes, self.obs["node"], self.obs["heading"], self.actions.numpy())))
            if cfg.location_coef:
                rollout.offsets.append(torch.from_numpy(target_offsets(
                    self.env.current_episodes, self.obs["node"], self.obs["heading"])))
            if self.refining:
                # f^R learns what acting computed: refine(estimate_t, memory before step t), not the
                # memory after it (that is refined_t itself).
                rollout.memory.append(self.previous_memory.cpu().clone(memory_format=torch.channels_last))
                sliced = self.separation.sliced
                rollout.monaural.append(_sliced(self.separation.monaural if sliced is None else sliced.monaural, s))
                rollout.target.append(_sliced(self.quality.mag, s))
            tock = time.perf_counter()
            self.times[2] += tock - tick

            if pending is not None and pending.quality is not None:
                pending.quality.start()  # the last step's measures, beside the env's (mostly one-threaded) step
            obs, env_reward, terminated, truncated, info = self.env.step(self.actions[action].numpy())
            done = terminated | truncated
            tick = time.perf_counter()
            self.times[0] += tick - tock

            ended = np.flatnonzero(done)
            classes, final = self._classes(), None
            if len(ended):
                final_obs = info["final_observation"]
                final = self.runner.step(final_obs["audio"][ended], self.last_classes[ended],
                                         np.zeros(len(ended), bool), rows=ended, keys=_poses(final_obs, ended))
            previous_memory = self.runner.memory.clone() if self.refining else None  # refines this estimate
            separation = self.runner.step(obs["audio"], classes, done, keys=_poses(obs))
            step_reward = self._reward(obs, info, env_reward, separation, final, ended)
            if pending is not None:
                self._settle(pending, rollout, finished)
            pending = step_reward
            self.last_classes = classes
            self.times[1] += time.perf_counter() - tick

            rollout.dones.append(torch.from_numpy(done.copy()))
            self.obs, self.separation, self.starts = obs, separation, done.copy()
            self.previous_memory = previous_memory
            self.env_steps += cfg.n_envs * self.world
        tick = time.perf_counter()
        self._settle(pending, rollout, finished)
        self.times[1] += time.perf_counter() - tick
        tick = time.perf_counter()
        with torch.no_grad():
            inputs = self._inputs(self.obs, self.separation).to(self.device)
            next_value = self.net.step(inputs, self.hidden, torch.from_numpy(self.starts).to(self.device)).value.cpu()
        self.times[2] += time.perf_counter() - tick
        return rollout, next_value, finished

    def _teacher_acts(self, action: torch.Tensor) -> None:
        """Slots [0, teacher_slots) take the approach teacher's action instead (in place)."""
        k = self.config.teacher_slots
        probabilities = teacher_probabilities(self.env.current_episodes[:k], self.obs["node"][:k],
                                              self.obs["heading"][:k], self.actions.numpy())
        action[:k] = torch.multinomial(torch.from_numpy(probabilities), 1, generator=self.generator)[:, 0]

    def _reward(self, obs: dict, info: dict, env_reward: np.ndarray, separation: SeparationStep,
                final: SeparationStep | None, ended: np.ndarray) -> _StepReward:
        """The kind's reward of the step just taken (pi^Q's: submitted to ``self.quality``, settled later)."""
        kind = self.config.spec.reward
        success = info["final_info"]["success"].copy() if len(ended) else None
        if kind == "navigation":
            return _StepReward(ended, success, reward=env_reward.astype(np.float64))
        if kind == "novelty":
            nodes = obs["node"].copy()
            if len(ended):
                nodes[ended] = info["final_observation"]["node"][ended]
            rows = np.arange(len(nodes))
            self.visits[rows, nodes] += 1
            reward = 1.0 / np.sqrt(self.visits[rows, nodes])
            self.visits[ended] = 0
            self.visits[ended, obs["node"][ended]] = 1
            return _StepReward(ended, success, reward=reward)
        refined = separation.refined.copy()  # the estimate after the step: an ended episode's last one
        if final is not None:
            refined[ended] = final.refined
        pending = self.quality.submit(refined, ended, separation.refined[ended], info["target_monaural"][ended])
        navigation = self.config.navigation_coef * env_reward.astype(np.float64) if self.config.navigation_coef else None
        return _StepReward(ended, success, reward=navigation, quality=pending)

    def _settle(self, step: _StepReward, rollout: _Rollout, finished: list[dict[str, float]]) -> None:
        """Account a step's reward (in step order): the rollout's rewards, returns, finished episodes."""
        reward = step.reward if step.quality is None else self.quality.settle(step.quality)
        if step.quality is not None and step.reward is not None:
            reward = reward + step.reward
        self.returns += reward
        self.lengths += 1
        for slot in step.ended.tolist():
            record = {"return": float(self.returns[slot]), "length": int(self.lengths[slot]),
                      "success": float(step.success[slot])}
            if step.quality is not None:
                record["final_nmse"] = float(self.quality.final_nmse[slot])
                record["final_quality"] = float(self.quality.final_quality[slot])
            finished.append(record)
        self.returns[step.ended], self.lengths[step.ended] = 0.0, 0
        rollout.rewards.append(torch.from_numpy(reward.astype(np.float32)))

    # ------------------------------------------------------------------ update
    def _decay(self) -> float:
        return 1.0 - self.update / self.config.updates if self.config.linear_decay else 1.0

    def _update_policy(self, rollout: _Rollout, next_value: torch.Tensor) -> dict[str, float]:
        cfg, dev = self.config, self.device
        n = cfg.n_envs
        rewards, values = torch.stack(rollout.rewards), torch.stack(rollout.values)
        dones, starts = torch.stack(rollout.dones), torch.stack(rollout.starts)
        advantages = gae(rewards, values, dones, next_value, gamma=cfg.gamma, lam=cfg.gae_lambda)
        returns = advantages + values
        moments = all_reduce_sum(np.array([advantages.sum().item(), advantages.square().sum().item(),
                                            advantages.numel()]), self.world, dev)
        mean = moments[0] / moments[2]
        std = math.sqrt(max(moments[1] / moments[2] - mean ** 2, 0.0))
        advantages = (advantages - mean) / (std + 1e-5)
        inputs = rollout.inputs
        actions, old_log_probs = torch.stack(rollout.actions), torch.stack(rollout.log_probs)
        clip = cfg.clip * self._decay()
        for group in self.optimizer.param_groups:
            group["lr"] = cfg.lr * self._decay()
        teacher = torch.stack(rollout.teacher) if cfg.teacher_coef else None
        teacher_weight = cfg.teacher_coef * self._decay()
        offsets = torch.stack(rollout.offsets) if cfg.location_coef else None
        params = self._policy_parameters()
        sums, count = np.zeros(6), 0
        per_batch = n // cfg.n_minibatches
        for _ in range(cfg.ppo_epochs):
            order = self.rng.permutation(n)
            for b in range(cfg.n_minibatches):
                # Sorted: one minibatch of all slots then needs no copy of the inputs.
                slots = torch.from_numpy(np.sort(order[b * per_batch: (b + 1) * per_batch]))
                rows = slice(None) if per_batch == n else slots
                batch = PolicyInputs(*(None if x is None else x[:, rows] for x in inputs)).flat().to(dev)
                out = self.net.evaluate(batch, self.hidden_start[slots.to(dev)], starts[:, slots].to(dev))
                log_probs_all = torch.log_softmax(out.logits, dim=-1)
                log_prob = log_probs_all.gather(2, actions[:, slots, None].to(dev))[..., 0]
                entropy = -(log_probs_all.exp() * log_probs_all).sum(-1).mean()
                ratio = torch.exp(log_prob - old_log_probs[:, slots].to(dev))
                adv = advantages[:, slots].to(dev)
                action_loss = -torch.min(ratio * adv, ratio.clamp(1 - clip, 1 + clip) * adv).mean()
                old_values, target = values[:, slots].to(dev), returns[:, slots].to(dev)
                clipped = old_values + (out.value - old_values).clamp(-clip, clip)
                value_loss = 0.5 * torch.max((out.value - target).square(), (clipped - target).square()).mean()
                loss = cfg.action_coef * action_loss + cfg.value_coef * value_loss - cfg.entropy * entropy
                if teacher is None:
                    teacher_ce = torch.tensor(float("nan"))
                else:  # kickstarting: cross-entropy from the teacher's distribution at the states visited
                    teacher_ce = -(teacher[:, slots].to(dev) * log_probs_all).sum(-1).mean()
                    loss = loss + teacher_weight * teacher_ce
                if offsets is None:
                    where_loss = where_error = torch.tensor(float("nan"))
                else:  # the auxiliary task: where the target is, from the GRU's output
                    where_loss, where_error = location_loss(self.location_head(out.outputs), offsets[:, slots].to(dev))
                    loss = loss + cfg.location_coef * where_loss
                self.optimizer.zero_grad()
                loss.backward()
                self._step(self.optimizer, params)
                sums += [value_loss.item(), action_loss.item(), entropy.item(), teacher_ce.item(), where_loss.item(),
                         where_error.item()]
                count += 1
        return dict(zip(POLICY_LOSSES, (sums / count).tolist(), strict=True))

    def _policy_parameters(self) -> list[torch.nn.Parameter]:
        """What the PPO optimiser steps: the policy's, and the location head's when there is one."""
        head = [] if self.location_head is None else list(self.location_head.parameters())
        return [*self.net.parameters(), *head]

    def _step(self, optimizer: torch.optim.Optimizer, params: list[torch.nn.Parameter]) -> None:
        """All-reduce (DD-PPO), clip the gradient norm, step."""
        for p in params:
            if p.grad is None:
                p.grad = torch.zeros_like(p)
        all_reduce_mean([p.grad for p in params], self.world)
        torch.nn.utils.clip_grad_norm_(params, self.config.max_grad_norm)
        optimizer.step()

    def _update_refiner(self, rollout: _Rollout) -> float:
        """L1 of f^R(f^M estimate, stored memory) to the ground-truth magnitude (f^B, f^M frozen)."""
        cfg, dev = self.config, self.device
        # Time-major flat (T * N, ...), channels_last kept; rows t * N + slot.
        monaural, memory = torch.cat(rollout.monaural), torch.cat(rollout.memory)
        target, starts = torch.cat(rollout.target), torch.stack(rollout.starts)
        steps = torch.arange(cfg.n_steps)[:, None] * cfg.n_envs
        params = list(self.separator.refiner.parameters())
        per_batch = cfg.n_envs // cfg.n_minibatches
        total, count = 0.0, 0
        for _ in range(cfg.refiner_epochs):
            order = self.rng.permutation(cfg.n_envs)
            for b in range(cfg.n_minibatches):
                slots = torch.from_numpy(order[b * per_batch: (b + 1) * per_batch])
                rows = (steps + slots[None]).flatten()  # = [:, slots].flatten(0, 1) of (T, N, ...)
                refined = self.separator.refine(monaural[rows].to(dev), memory[rows].to(dev),
                                                starts[:, slots].flatten().to(dev))
                loss = F.l1_loss(refined, target[rows].to(dev))
                self.refiner_optimizer.zero_grad()
                loss.backward()
                self._step(self.refiner_optimizer, params)
                total, count = total + loss.item(), count + 1
        return total / count

    @property
    def refining(self) -> bool:
        return self.config.refiner_trained

    # ------------------------------------------------------------------ checkpoints
    def _state(self) -> dict[str, Any]:
        """Everything needed to continue exactly (tensors and plain types: loads weights-only)."""
        sep = self.separation
        return {
            "config": self.config.to_dict(), "update": self.update, "env_steps": self.env_steps,
            "history": self.history, "windows": {k: list(v) for k, v in self.windows.items()},
            "wall": self.wall_before + time.perf_counter() - self.session_start,
            "net": self.net.state_dict(), "optimizer": self.optimizer.state_dict(),
            "location_head": None if self.location_head is None else self.location_head.state_dict(),
            "refiner": self.separator.refiner.state_dict(), "refiner_optimizer": self.refiner_optimizer.state_dict(),
            "generator": self.generator.get_state(), "rng": self.rng.bit_generator.state,
            "env": self.env.state(),
            "obs": _to_tensors(self.obs),
            "separation": _to_tensors({name: getattr(sep, name) for name in ("binaural", "monaural", "refined")}),
            "memory": self.runner.memory.cpu(),
            "previous_memory": None if self.previous_memory is None else self.previous_memory.cpu(),
            "hidden": self.hidden.cpu(),
            "episode": _to_tensors({"starts": self.starts, "returns": self.returns, "lengths": self.lengths,
                                    "visits": self.visits, "last_classes": self.last_classes,
                                    **self.quality.state()}),
        }

    def _restore(self, state: dict[str, Any]) -> None:
        ours = self.config.to_dict()
        # A setting added after the state was written counts as its default there (the env's too).
        theirs = _with_defaults(PPOConfig().to_dict(), state["config"])
        if theirs != ours:
            changed = sorted(k for k in set(ours) | set(theirs) if ours.get(k) != theirs.get(k))
            raise CheckpointError(f"{self.resume_path} was written by a run with other settings ({', '.join(changed)}); "
                                  f"use another --out or --fresh")
        self.update, self.env_steps, self.history = state["update"], state["env_steps"], state["history"]
        for key, values in state["windows"].items():
            self.windows[key].extend(values)
        self.wall_before = state["wall"]
        self.net.load_state_dict(state["net"])
        self.optimizer.load_state_dict(state["optimizer"])
        if self.location_head is not None:
            self.location_head.load_state_dict(state["location_head"])
        self.separator.refiner.load_state_dict(state["refiner"])
        self.refiner_optimizer.load_state_dict(state["refiner_optimizer"])
        self.generator.set_state(state["generator"])
        self.rng.bit_generator.state = state["rng"]
        self.env.restore(state["env"])
        self.obs = _to_arrays(state["obs"])
        self.separation = SeparationStep(**_to_arrays(state["separation"]))
        self.runner.memory = state["memory"].to(self.device)
        if "previous_memory" not in state:
            raise CheckpointError(f"{self.resume_path} was written before f^R's training memory was fixed; "
                                  f"use another --out or --fresh")
        previous = state["previous_memory"]
        self.previous_memory = None if previous is None else previous.to(self.device)
        self.hidden = state["hidden"].to(self.device)
        episode = _to_arrays(state["episode"])
        for key in ("starts", "returns", "lengths", "visits", "last_classes"):
            setattr(self, key, episode[key])
        self.quality.restore(episode)

    def _write(self) -> Path:
        """Checkpoint: this worker's resume state; rank 0 also the policy, separator, log and curve."""
        self.out_dir.mkdir(parents=True, exist_ok=True)
        tmp = self.resume_path.with_suffix(".tmp")
        torch.save(self._state(), tmp)
        os.replace(tmp, self.resume_path)
        policy = self.out_dir / "policy.pt"
        if self.rank == 0:
            wall = self.wall_before + time.perf_counter() - self.session_start
            metadata = {"command": self.command, "updates": self.update, "env_steps": self.env_steps,
                        "wall_seconds": round(wall, 1), "workers": self.world, "machine": machine_description(),
                        "separator": repo_relative(self.loaded.path), "refiner_trained": self.refining,
                        "config": self.config.to_dict()}
            save_policy(policy, self.net, policy_kind=self.config.kind, stft_config=self.loaded.stft,
                        metadata=metadata)
            if self.refining:  # the separator it started from, and how this run trained its f^R
                refiner_run = {key: metadata[key] for key in ("command", "updates", "env_steps", "wall_seconds",
                                                              "machine", "separator")}
                separator_metadata = {**self.loaded.metadata,
                                      "refiner_trained_with": {**refiner_run, "policy": str(policy)}}
                save_separator(self.out_dir / "separator.pt", self.separator, classes=self.loaded.classes,
                               stft_config=self.loaded.stft, metadata=separator_metadata, metadata_json=True)
            with open(self.out_dir / "log.csv", "w", newline="") as f:
                writer = csv.DictWriter(f, fieldnames=list(self.history[0]))
                writer.writeheader()
                writer.writerows(self.history)
            plot_curve(self.out_dir / "curve.png", self.history, kind=self.config.kind)
        if self.world > 1:
            dist.barrier()
        return policy

    # ------------------------------------------------------------------ the loop
    def run(self, *, fresh: bool = False, stop_after: int | None = None) -> TrainResult:
        """Train up to ``config.updates`` (continuing a resume state unless ``fresh``); ``stop_after``
        ends this session (with a checkpoint) after that many updates."""
        cfg = self.config
        self.session_start = time.perf_counter()
        if self.resume_path.is_file() and not fresh:
            self._restore(torch.load(self.resume_path, weights_only=True))
        else:
            self._begin()
        if self.rank == 0:
            self.out_dir.mkdir(parents=True, exist_ok=True)
            (self.out_dir / "config.json").write_text(json.dumps(cfg.to_dict(), indent=2) + "\n")
        bar = tqdm(total=cfg.updates, initial=self.update, desc=f"PPO {cfg.kind}", unit="update",
                   disable=not self.progress)
        policy = self.out_dir / "policy.pt"
        session_updates = 0
        try:
            while self.update < cfg.updates and (stop_after is None or session_updates < stop_after):
                started, cpu, times_before = time.perf_counter(), time.process_time(), self.times.copy()
                rollout, next_value, finished = self._collect()
                tick = time.perf_counter()
                losses = (dict.fromkeys(POLICY_LOSSES, float("nan")) if cfg.frozen_policy
                          else self._update_policy(rollout, next_value))
                self.times[3] += time.perf_counter() - tick
                tick = time.perf_counter()
                losses["refiner_l1"] = self._update_refiner(rollout) if self.refining else float("nan")
                self.times[4] += time.perf_counter() - tick
                self.update += 1
                session_updates += 1
                self._log(finished, losses, time.perf_counter() - started, time.process_time() - cpu,
                          self.times - times_before)
                bar.update()
                bar.set_postfix(ret=f"{self.history[-1]['return_window']:.3f}", sps=f"{self.history[-1]['sps']:.0f}")
                if self.update % cfg.checkpoint_every == 0 or self.update == cfg.updates \
                        or session_updates == stop_after:
                    policy = self._write()
        finally:
            bar.close()
        return TrainResult(self.net, self.out_dir, self.history, policy)

    def _log(self, finished: list[dict[str, float]], losses: dict[str, float], seconds: float, cpu: float,
             times: np.ndarray) -> None:
        keys = WINDOWED
        local = np.array([len(finished)] + [sum(r.get(k, 0.0) for r in finished) for k in keys])
        totals = all_reduce_sum(local, self.world, self.device)
        episodes = int(totals[0])
        for key, total in zip(keys, totals[1:], strict=True):
            if episodes:
                self.windows[key].append(float(total / episodes))
        steps = self.config.n_envs * self.config.n_steps * self.world

        def window(key: str) -> float:
            return float(np.mean(self.windows[key])) if self.windows[key] else float("nan")

        self.history.append({
            "update": self.update, "env_steps": self.env_steps, "episodes": episodes,
            "return_window": window("return"), "final_nmse_window": window("final_nmse"),
            "final_quality_window": window("final_quality"),
            "success_window": window("success"), **losses, "lr": self.config.lr * self._decay(),
            "sps": steps / seconds, "cpu_ms_per_step": 1e3 * cpu * self.world / steps, **{f"{part}_share": float(share / seconds)
                                       for part, share in zip(TIMED_PARTS, times, strict=True)},
        })


def train(config: PPOConfig, library: SoundLibrary, *, out_dir: Path, rir_cache_dir: Path | None = None,
          progress: bool = True, command: str | None = None, fresh: bool = False,
          stop_after: int | None = None) -> TrainResult:
    """Train (or continue, when ``out_dir`` holds a resume state of the same settings) one policy."""
    trainer = PPOTrainer(config, library, out_dir=out_dir, rir_cache_dir=rir_cache_dir, progress=progress,
                         command=command)
    try:
        return trainer.run(fresh=fresh, stop_after=stop_after)
    finally:
        trainer.env.close()
