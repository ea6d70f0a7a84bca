"""Train the Gan et al. baseline's sound locator (``m2h_ros.models.locator``) by supervised learning.

    python -m m2h_ros.training.train_locator [--samples 30000] [--epochs 12] [--out PATH]

Data: single observations drawn from far-target episodes of the training scenes with heard sounds
(validation: val scenes, unheard sounds, as the test conditions), the robot placed on a node drawn
uniformly from the scene and a heading drawn uniformly, and on the target's node in
``at_target_fraction`` of the draws (so the Stop head sees enough positives). Labels come from the
simulator: the target's position relative to the robot (metres, forward and left) and whether the
robot stands on the target's node. Sample i of a set is a pure function of (seed, i).

Loss: smooth L1 of the offset (metres) + binary cross-entropy of the Stop head; Adam; the epoch with
the lowest validation loss is kept. Outputs: the checkpoint (with its metadata: command, data,
losses, validation errors), ``<stem>.json`` and ``<stem>_loss.png``.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import os
import shlex
import sys
import time
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path

os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")  # before torch loads (see pretrain_separator)

import numpy as np  # noqa: E402
import torch  # noqa: E402
import torch.nn.functional as F  # noqa: E402
from tqdm import tqdm  # noqa: E402

from m2h_ros.core.sounds.library import SoundLibrary  # noqa: E402
from m2h_ros.core.world.env import BatchEnv, EnvConfig  # noqa: E402
from m2h_ros.core.world.episodes import EpisodeConfig, draw_episode  # noqa: E402
from m2h_ros.core.world.worlds import worlds_of  # noqa: E402
from m2h_ros.config import check_int_fields  # noqa: E402
from m2h_ros.errors import ConfigError, reports_errors  # noqa: E402
from m2h_ros.models.locator import (DEFAULT_LOCATOR_CHECKPOINT, LocatorConfig, LocatorOutput,  # noqa: E402
                                    SoundLocator, locator_input, relative_offset, save_locator)
from m2h_ros.paths import repo_relative  # noqa: E402
from m2h_ros.training.plots import save_panels, two_panels  # noqa: E402
from m2h_ros.training.separator_data import StreamConfig, build_banks  # noqa: E402

_SALT = 0x6C6F63  # separates the locator's draws from other uses of the same seed


def _train_episodes() -> EpisodeConfig:
    return EpisodeConfig(task="far_target", scene_split="train", sound_split="heard")


def _val_episodes() -> EpisodeConfig:
    return EpisodeConfig(task="far_target", scene_split="val", sound_split="unheard")


def _audio_only() -> EnvConfig:
    return EnvConfig(camera=False)


@dataclass(frozen=True)
class LocatorTrainConfig:
    model: LocatorConfig = field(default_factory=LocatorConfig)
    train_episodes: EpisodeConfig = field(default_factory=_train_episodes)  # templates: scenes, sounds
    val_episodes: EpisodeConfig = field(default_factory=_val_episodes)
    env: EnvConfig = field(default_factory=_audio_only)
    samples: int = 30_000
    val_samples: int = 2_000
    at_target_fraction: float = 0.2
    epochs: int = 12
    batch_size: int = 64
    lr: float = 1e-3
    stop_weight: float = 1.0  # BCE weight beside the offset's smooth L1 (metres)
    seed: int = 0
    threads: int = 2

    def __post_init__(self) -> None:
        check_int_fields(self, (("samples", 1), ("val_samples", 1), ("epochs", 1), ("batch_size", 1), ("seed", 0),
                                ("threads", 1)))
        if not 0.0 <= self.at_target_fraction < 1.0:
            raise ConfigError(f"LocatorTrainConfig.at_target_fraction={self.at_target_fraction!r} must be in [0, 1)")
        if not (isinstance(self.lr, float) and 0 < self.lr < 1) or not self.stop_weight >= 0:
            raise ConfigError("LocatorTrainConfig.lr must be in (0, 1) and stop_weight >= 0")
        if self.env.camera:
            raise ConfigError("LocatorTrainConfig.env must have camera=False (the locator hears only)")


@dataclass(frozen=True)
class LocatorSet:
    inputs: torch.Tensor  # (n, 3, bands, T) float16
    offsets: torch.Tensor  # (n, 2) float32 metres, (forward, left)
    at_target: torch.Tensor  # (n,) float32 0/1


def draw_set(config: LocatorTrainConfig, template: EpisodeConfig, library: SoundLibrary, *, count: int,
             seed: int, progress: bool = True, what: str = "locator data") -> LocatorSet:
    """``count`` labelled observations of ``template``'s scenes and sounds, rendered in batches of 16."""
    scenes = worlds_of(template.scene_split, preset=template.scene_preset)
    batch = 16
    env: BatchEnv | None = None
    inputs, offsets, at_target = [], [], []
    try:
        for start in tqdm(range(0, count, batch), desc=what, unit="batch", disable=not progress):
            rng = np.random.default_rng([seed, _SALT, start])
            episodes, targets = [], []
            for j in range(min(batch, count - start)):
                episode = draw_episode(rng, template, int(rng.integers(len(scenes))), library,
                                       episode_id=f"locator/{start + j}")
                grid = episode.scene().grid
                node = (episode.target_node if rng.random() < config.at_target_fraction
                        else int(rng.integers(grid.n_nodes)))
                episodes.append(dataclasses.replace(episode, start_node=node, start_heading=int(rng.integers(4))))
                targets.append(grid.positions[episode.target_node])
            while len(episodes) < batch:  # the env's slots are fixed: pad the last batch, drop the padding
                episodes.append(episodes[-1])
            if env is None:
                env = BatchEnv(episodes, library, n_envs=batch, config=config.env, autoreset=False, pose_cache=0)
            obs, info = env.reset(episodes=episodes)
            n = len(targets)
            inputs.append(locator_input(obs["audio"][:n], obs["target_class"][:n], bands=config.model.bands,
                                        config=config.env.stft).half())
            offsets.append(torch.from_numpy(relative_offset(np.array(targets), obs["pose"][:n])))
            at_target.append(torch.from_numpy(info["at_target"][:n].astype(np.float32)))
    finally:
        if env is not None:
            env.close()
    return LocatorSet(torch.cat(inputs), torch.cat(offsets), torch.cat(at_target))


def _losses(out: LocatorOutput, offsets: torch.Tensor, at_target: torch.Tensor,
            stop_weight: float) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    offset_loss = F.smooth_l1_loss(out.offset, offsets)
    stop_loss = F.binary_cross_entropy_with_logits(out.stop_logit, at_target)
    return offset_loss + stop_weight * stop_loss, offset_loss, stop_loss


@torch.no_grad()
def evaluate(net: SoundLocator, data: LocatorSet, *, stop_weight: float = 1.0) -> dict[str, float]:
    """Losses, the median position error (m), the median bearing error (degrees, away from the
    target's node) and the Stop head's accuracy at and away from the target."""
    net.eval()
    out = net(data.inputs.float())
    loss, offset_loss, stop_loss = _losses(out, data.offsets, data.at_target, stop_weight)
    error = (out.offset - data.offsets).norm(dim=1)
    away = data.at_target < 0.5
    bearing = torch.atan2(out.offset[:, 1], out.offset[:, 0]) - torch.atan2(data.offsets[:, 1], data.offsets[:, 0])
    bearing = torch.rad2deg(torch.atan2(torch.sin(bearing), torch.cos(bearing))).abs()
    stop = out.stop_logit > 0
    at = ~away
    return {"loss": float(loss), "offset_loss": float(offset_loss), "stop_loss": float(stop_loss),
            "median_error_m": float(error.median()), "median_distance_m": float(data.offsets.norm(dim=1).median()),
            "median_bearing_error_deg": float(bearing[away].median()) if away.any() else float("nan"),
            "stop_recall": float(stop[at].float().mean()) if at.any() else float("nan"),
            "stop_false_alarm": float(stop[away].float().mean()) if away.any() else float("nan")}


STOP_THRESHOLDS = (0.5, 0.7, 0.9)
STOP_RADII = (1.0, 1.5, 100.0)  # 100: the offset ignored


@torch.no_grad()
def stop_rule_table(net: SoundLocator, data: LocatorSet) -> list[dict[str, float]]:
    """Per (threshold, radius): how often the Gan controller's Stop rule (probability > threshold and
    predicted offset < radius) fires at the target's node and away from it, per observation."""
    net.eval()
    out = net(data.inputs.float())
    p, near = torch.sigmoid(out.stop_logit), out.offset.norm(dim=1)
    at = data.at_target > 0.5
    rows = []
    for threshold in STOP_THRESHOLDS:
        for radius in STOP_RADII:
            fires = (p > threshold) & (near < radius)
            rows.append({"threshold": threshold, "radius_m": radius, "recall": float(fires[at].float().mean()),
                         "false_alarm": float(fires[~at].float().mean())})
    return rows


def plot_curve(path: Path, history: list[dict[str, float]]) -> Path:
    fig, (left, right) = two_panels((10, 3.8))
    epochs = [h["epoch"] for h in history]
    for key, style in (("train_loss", "C0--"), ("val_loss", "C0-"), ("val_stop_loss", "C1-")):
        left.plot(epochs, [h[key] for h in history], style, marker="o", ms=3, label=key.replace("_", " "))
    right.plot(epochs, [h["val_median_error_m"] for h in history], "C2-", marker="o", ms=3, label="val median error (m)")
    right.plot(epochs, [h["val_median_distance_m"] for h in history], "k:", label="val median distance (m)")
    left.set(title="sound locator", xlabel="epoch", ylabel="loss")
    right.set(title="validation (val scenes, unheard sounds)", xlabel="epoch", ylabel="metres")
    return save_panels(fig, (left, right), path)


def train_locator(config: LocatorTrainConfig, library: SoundLibrary, *, out: Path, command: str | None = None,
                  progress: bool = True) -> dict:
    """Draw the data, train, write the best epoch's checkpoint with its metadata; returns the metadata."""
    started = time.perf_counter()
    torch.set_num_threads(config.threads)
    torch.manual_seed(config.seed)
    for template in (config.train_episodes, config.val_episodes):
        build_banks(StreamConfig(episodes=(template,), env=config.env), progress=progress)
    train = draw_set(config, config.train_episodes, library, count=config.samples, seed=config.seed,
                     progress=progress, what="locator train data")
    val = draw_set(config, config.val_episodes, library, count=config.val_samples, seed=config.seed + 1,
                   progress=progress, what="locator val data")
    data_seconds = time.perf_counter() - started
    net = SoundLocator(config.model, stft_config=config.env.stft)
    optimizer = torch.optim.Adam(net.parameters(), lr=config.lr)
    generator = torch.Generator().manual_seed(config.seed)
    history, best = [], None
    for epoch in range(1, config.epochs + 1):
        net.train()
        order = torch.randperm(len(train.offsets), generator=generator)
        total, batches = 0.0, 0
        bar = tqdm(range(0, len(order), config.batch_size), desc=f"locator epoch {epoch}/{config.epochs}",
                   unit="batch", leave=False, disable=not progress)
        for first in bar:
            rows = order[first:first + config.batch_size]
            loss, _, _ = _losses(net(train.inputs[rows].float()), train.offsets[rows], train.at_target[rows],
                                 config.stop_weight)
            optimizer.zero_grad()
            loss.backward()
            optimizer.step()
            total, batches = total + loss.item(), batches + 1
        scores = evaluate(net, val, stop_weight=config.stop_weight)
        record = {"epoch": epoch, "train_loss": total / batches, **{f"val_{k}": v for k, v in scores.items()}}
        history.append(record)
        if progress:
            tqdm.write(", ".join(f"{k} {v:.3f}" if isinstance(v, float) else f"{k} {v}" for k, v in record.items()))
        if best is None or scores["loss"] < best[1]:
            best = (epoch, scores["loss"], {k: v.clone() for k, v in net.state_dict().items()})
    net.load_state_dict(best[2])
    metadata = {
        "stop_rule": stop_rule_table(net, val),
        "command": command or "train_locator()",
        "config": {k: v for k, v in dataclasses.asdict(config).items() if k != "model"},
        "best_epoch": best[0], "final": {k: v for k, v in history[best[0] - 1].items() if k != "epoch"},
        "history": history,
        "wall_seconds": {"data": round(data_seconds, 1), "total": round(time.perf_counter() - started, 1)},
    }
    out = Path(out)
    save_locator(out, net.eval(), stft_config=config.env.stft, metadata=metadata)
    out.with_suffix(".json").write_text(json.dumps(metadata, indent=1) + "\n")
    plot_curve(out.with_name(f"{out.stem}_loss.png"), history)
    return metadata


@reports_errors("train_locator")
def main(argv: Sequence[str] | None = None) -> int:
    defaults = LocatorTrainConfig()
    parser = argparse.ArgumentParser(description="Train the Gan et al. baseline's sound locator (supervised).")
    parser.add_argument("--samples", type=int, default=defaults.samples, help="training observations")
    parser.add_argument("--val-samples", type=int, default=defaults.val_samples)
    parser.add_argument("--epochs", type=int, default=defaults.epochs)
    parser.add_argument("--seed", type=int, default=defaults.seed)
    parser.add_argument("--threads", type=int, default=defaults.threads)
    parser.add_argument("--out", type=Path, default=DEFAULT_LOCATOR_CHECKPOINT)
    args = parser.parse_args(argv)
    config = LocatorTrainConfig(samples=args.samples, val_samples=args.val_samples, epochs=args.epochs,
                                seed=args.seed, threads=args.threads)
    command = shlex.join([Path(sys.argv[0]).name, *(sys.argv[1:] if argv is None else argv)])
    meta = train_locator(config, SoundLibrary.load(), out=args.out, command=command)
    final = meta["final"]
    print(f"wrote {repo_relative(args.out)} in {meta['wall_seconds']['total']:.0f} s (best epoch {meta['best_epoch']}): "
          f"val median error {final['val_median_error_m']:.2f} m at a median {final['val_median_distance_m']:.2f} m, "
          f"bearing {final['val_median_bearing_error_deg']:.0f} deg, Stop recall {final['val_stop_recall']:.2f}, "
          f"false alarms {final['val_stop_false_alarm']:.3f}")
    for row in meta["stop_rule"]:
        print(f"  Stop if p > {row['threshold']:.1f} and predicted offset < {row['radius_m']:g} m: fires at the "
              f"target {row['recall']:.2f}, elsewhere {row['false_alarm']:.4f} per observation (val)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
