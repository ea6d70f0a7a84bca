"""Diagnostic: how much of the approach teacher's action can a policy read from what it hears?

Kickstarting (``training.teacher``) asks the policy to predict, from its own inputs, the next step of
a shortest path to the target. This probe measures how predictable that is: it collects the rollouts
of an untrained policy (the PPO trainer's own collection: its separator, inputs and teacher labels)
and fits small classifiers from the interaural level difference (ILD) spectrum of the separated
binaural estimate, log(1 + |L|) - log(1 + |R|) averaged over time per frequency row (what a binaural
ear can localise with, without phase), to the teacher's distribution. Reported per fit: the held-out
cross-entropy against the label prior's (no information) and the teacher's own entropy (everything),
and how often the ILD's sign alone names the teacher's turn.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch

from m2h_ros.core.world.episodes import TURN_LEFT, TURN_RIGHT
from m2h_ros.training.ppo import PPOTrainer


@dataclass(frozen=True)
class ProbeData:
    """Per visited state: ILD spectrum (n, rows) and the teacher's distribution (n, outputs)."""

    ild: np.ndarray
    teacher: np.ndarray
    env_actions: np.ndarray  # environment action of each teacher column


def collect_probe_data(trainer: PPOTrainer, rollouts: int) -> ProbeData:
    """``rollouts`` rollouts of the trainer's (untrained) policy; the trainer must have a teacher."""
    trainer._begin()
    ild, teacher = [], []
    for _ in range(rollouts):
        rollout, _, _ = trainer._collect()
        audio = rollout.inputs.audio.flatten(0, 1).float()  # (T * N, 2S, H, W): log(1 + |f^B|), left then right
        s = audio.shape[1] // 2
        ild.append((audio[:, :s] - audio[:, s:]).mean(-1).flatten(1).numpy())
        teacher.append(torch.stack(rollout.teacher).flatten(0, 1).numpy())
    return ProbeData(np.concatenate(ild), np.concatenate(teacher), trainer.actions.numpy())


def cross_entropy(teacher: np.ndarray, log_probs: np.ndarray) -> float:
    return float(-(teacher * log_probs).sum(-1).mean())


def fit_probe(data: ProbeData, *, hidden: int = 0, epochs: int = 60, held_out: float = 0.2,
              seed: int = 0) -> dict[str, float]:
    """Fit a linear (``hidden`` 0) or one-hidden-layer classifier on the first ``1 - held_out`` of the
    states; the best held-out cross-entropy over epochs (an early-stopping optimum: an upper bound of
    what this probe reads), beside the prior's and the teacher's entropy on the same states."""
    n_val = max(1, int(len(data.ild) * held_out))
    x, y = torch.from_numpy(data.ild).float(), torch.from_numpy(data.teacher).float()
    x_val, y_val, x_fit, y_fit = x[:n_val], y[:n_val], x[n_val:], y[n_val:]
    mean, std = x_fit.mean(0), x_fit.std(0) + 1e-6
    x_fit, x_val = (x_fit - mean) / std, (x_val - mean) / std
    prior = y_fit.mean(0).clamp_min(1e-6)
    generator = torch.Generator().manual_seed(seed)
    torch.manual_seed(seed)
    width = x.shape[1]
    model = (torch.nn.Linear(width, y.shape[1]) if hidden == 0 else
             torch.nn.Sequential(torch.nn.Linear(width, hidden), torch.nn.ReLU(), torch.nn.Linear(hidden, y.shape[1])))
    optimizer = torch.optim.Adam(model.parameters(), lr=1e-3, weight_decay=1e-4)
    best = float("inf")
    for _ in range(epochs):
        order = torch.randperm(len(x_fit), generator=generator)
        for start in range(0, len(x_fit), 256):
            rows = order[start:start + 256]
            loss = -(y_fit[rows] * torch.log_softmax(model(x_fit[rows]), -1)).sum(-1).mean()
            optimizer.zero_grad()
            loss.backward()
            optimizer.step()
        with torch.no_grad():
            best = min(best, cross_entropy(y_val.numpy(), torch.log_softmax(model(x_val), -1).numpy()))
    teacher = y_val.numpy()
    return {"held_out_states": n_val, "prior_ce": cross_entropy(teacher, np.log(prior.numpy())),
            "teacher_entropy": cross_entropy(teacher, np.log(np.clip(teacher, 1e-12, None))) + 0.0,  # no -0.0
            "probe_ce": best}


def ild_sign_accuracy(data: ProbeData) -> tuple[float, int]:
    """Share of the states where the teacher turns (one turn certain) whose turn the mean ILD's sign
    names (louder left: TurnLeft), and how many such states there were."""
    columns = list(data.env_actions)
    left, right = data.teacher[:, columns.index(TURN_LEFT)], data.teacher[:, columns.index(TURN_RIGHT)]
    turning = (left == 1) | (right == 1)
    says_left = data.ild[turning].mean(1) > 0
    return float((says_left == (left[turning] == 1)).mean()) if turning.any() else float("nan"), int(turning.sum())
