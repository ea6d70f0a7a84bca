"""Pretrain the passive separator (f^B, f^M, then f^R) on data drawn on the fly from the simulator.

    python -m m2h_ros.training.pretrain_separator [--preset compact] [--backbone unet] [--seed 0] [--out PATH]

For a robot's own head: ``--head sofa:PATH`` (or ``free_field:SPACING_M``) renders every stream through
that head, and ``--init-from`` a checkpoint fine-tunes it (docs/how-to/robot-head.md).

Data (``separator_data``): every batch is a fresh draw (episode, walk, clips, gains, noise) from the
training scenes with heard sounds, rendered by DataLoader worker processes while the main process
trains; validation is a fixed set drawn once from the val scenes with unheard sounds, unaugmented.

Stage 1 (f^B + f^M, Adam 5e-4 as the seed says), batches of single observations:
  * f^B predicts a ratio mask on the mixture magnitude; loss L1(mask * |mixture|, |target share|),
    the target's share of the mixture being what a mask can reach;
  * f^M maps f^B's separated binaural magnitude to the target's dry monaural magnitude; loss L1.
    f^M's input is f^B's output *detached*: f^M learns on what f^B really produces (as at inference)
    while its loss does not pull f^B away from its own binaural target.
  Validation after every epoch, beside two references for f^B: the identity mask (the mixture as
  is) and the ideal mask (|share| / |mixture| capped at 1). The weights with the best validation f^M
  loss are kept.
Stage 2 (f^R): f^B and f^M frozen (eval mode); on sequences of consecutive observations the refiner
runs with its memory reset at the first step and the previous refined estimate carried over
(backpropagation through the sequence), loss L1 of every step's refined estimate to the monaural
target. Best validation epoch kept.

Resumable: after every epoch the whole training state (weights, optimizer, best weights, history,
stream position) is written atomically to ``<out stem>.state.pt``; running the same command again
continues from there (batches are a function of their index, so the continuation equals an
uninterrupted run). The epoch counts may change on resume: a run stopped during stage 1 and rerun
with ``--epochs`` = the epochs it completed goes on to stage 2 (a wall-clock budget without
guessing the throughput up front). The state file is removed when the run completes.

Outputs: the checkpoint (``save_separator``: model args, STFT, classes, metadata), ``<stem>.json``
(metadata: data, epochs, wall times, throughput, machine, losses, command) and ``<stem>_loss.png``.
"""

from __future__ import annotations

import argparse
import copy
import dataclasses
import hashlib
import math
import os
import shlex
import sys
import time
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

# Spinning OpenMP workers collapse torch's CPU speed on a shared, oversubscribed machine (measured
# with 2 threads at load 9 on 2 cores: 300 ms per training sample spinning, 14 ms passive); waiting
# passively costs little when the cores are free. Only takes effect if torch is not imported yet.
os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")

import numpy as np  # noqa: E402
import torch  # noqa: E402
import torch.nn.functional as F  # noqa: E402
from torch.utils.data import DataLoader  # noqa: E402
from tqdm import tqdm  # noqa: E402

from m2h_ros.core.sounds.library import TARGET_CATEGORIES, SoundLibrary  # noqa: E402
from m2h_ros.core.world.acoustics import BACKENDS, BACKEND_HELP, AcousticsConfig  # noqa: E402
from m2h_ros.core.world.env import EnvConfig  # noqa: E402
from m2h_ros.core.world.hrtf import HEAD_HELP, KEMAR  # noqa: E402
from m2h_ros.config import check_int_fields  # noqa: E402
from m2h_ros.errors import CheckpointError, ConfigError, reports_errors  # noqa: E402
from m2h_ros.models.device import DEVICES, check_device, resolve_device
from m2h_ros.models.checkpoint import PRETRAINED_SEPARATOR_CHECKPOINT, load_separator, save_separator  # noqa: E402
from m2h_ros.models.separator import BACKBONES, PRESET_NAMES, Separator, SeparatorConfig, count_parameters  # noqa: E402
from m2h_ros.machine import machine_description  # noqa: E402
from m2h_ros.paths import REPO_DIR, repo_relative  # noqa: E402
from m2h_ros.training.plots import save_panels, two_panels  # noqa: E402
from m2h_ros.training.separator_data import (  # noqa: E402
    BatchSource,
    SeparatorBatch,
    SeparatorStream,
    StreamConfig,
    build_banks,
    fixed_set,
)

STATE_VERSION = 1
STAGES = ("stage1", "stage2")


def _compact() -> SeparatorConfig:
    return SeparatorConfig.preset("compact")


def _stage1_stream() -> StreamConfig:
    return StreamConfig.training()


def _stage2_stream() -> StreamConfig:
    return StreamConfig.training(batch_size=8, steps=8)


def _validation_stream() -> StreamConfig:
    return StreamConfig.validation()


@dataclass(frozen=True)
class PretrainConfig:
    """Hyperparameters of one pretraining run (all but ``threads`` and ``workers`` change its result)."""

    model: SeparatorConfig = field(default_factory=_compact)
    seed: int = 0  # weights
    lr: float = 5e-4  # Adam, both stages (the seed's pretraining rate)
    # Stage 1 only: None keeps ``lr`` constant (the seed); a float anneals it to this value along a
    # cosine over the stage's batches (so then the epoch count is part of the result).
    final_lr: float | None = None
    init_from: str = ""  # a separator checkpoint whose weights stage 1 starts from ("" = fresh weights)
    epochs: int = 8  # stage 1 epochs of ...
    batches_per_epoch: int = 500  # ... this many batches of train_data
    refiner_epochs: int = 4
    refiner_batches_per_epoch: int = 100
    train_data: StreamConfig = field(default_factory=_stage1_stream)  # stage 1: single observations
    refiner_data: StreamConfig = field(default_factory=_stage2_stream)  # stage 2: sequences
    val_data: StreamConfig = field(default_factory=_validation_stream)
    val_batches: int = 4  # the fixed validation set: this many batches of val_data
    threads: int = 2  # torch intra-op threads of the training process
    workers: int = 1  # DataLoader worker processes rendering batches
    device: str = "auto"  # where the networks train: auto (CUDA when present), cpu or cuda

    def __post_init__(self) -> None:
        if not isinstance(self.model, SeparatorConfig):
            raise ConfigError(f"PretrainConfig.model must be a SeparatorConfig, got {type(self.model).__name__}")
        check_int_fields(self, (("seed", 0), ("epochs", 1), ("batches_per_epoch", 1), ("refiner_epochs", 1),
                                ("refiner_batches_per_epoch", 1), ("val_batches", 1), ("threads", 1), ("workers", 0)))
        if not (isinstance(self.lr, float) and 0 < self.lr < 1):
            raise ConfigError(f"PretrainConfig.lr must be a float in (0, 1), got {self.lr!r}")
        if self.final_lr is not None and not (isinstance(self.final_lr, float) and 0 < self.final_lr <= self.lr):
            raise ConfigError(f"PretrainConfig.final_lr must be None or a float in (0, lr], got {self.final_lr!r}")
        if not isinstance(self.init_from, str):
            raise ConfigError(f"PretrainConfig.init_from must be a checkpoint path string, got {self.init_from!r}")
        for name in ("train_data", "refiner_data", "val_data"):
            stream = getattr(self, name)
            if not isinstance(stream, StreamConfig):
                raise ConfigError(f"PretrainConfig.{name} must be a StreamConfig, got {type(stream).__name__}")
            if stream.env.stft != self.train_data.env.stft:
                raise ConfigError(f"PretrainConfig.{name} uses other STFT settings than train_data")
        if self.train_data.steps != 1:
            raise ConfigError("PretrainConfig.train_data must draw single observations (steps=1)")
        self.model.check_stft(self.train_data.env.stft)
        check_device(self.device, field="PretrainConfig.device")

    def torch_device(self) -> torch.device:
        return resolve_device(self.device, field="PretrainConfig.device")

    def result_fields(self) -> dict[str, Any]:
        """The fields a resumed run must share with the run it continues. Not the epoch counts while
        the learning rate is constant: batch i is the same in any run, so continuing with more (or
        fewer) epochs of the current stage is the run that had that many from the start."""
        # The device changes only the last bits (CUDA kernels): a run may resume on another one.
        free = {"threads", "workers", "device", "refiner_epochs"} | ({"epochs"} if self.final_lr is None else set())
        return {k: v for k, v in dataclasses.asdict(self).items() if k not in free}

    def stage1_lr(self, batch: int) -> float:
        """Stage 1's learning rate at its ``batch``-th batch (0-based)."""
        if self.final_lr is None:
            return self.lr
        progress = batch / max(self.epochs * self.batches_per_epoch - 1, 1)
        return self.final_lr + 0.5 * (self.lr - self.final_lr) * (1.0 + math.cos(math.pi * progress))


@dataclass
class PretrainResult:
    separator: Separator
    checkpoint: Path
    metadata: dict[str, Any]


@dataclass
class _State:
    """Everything a resumed run needs; written after every epoch."""

    stage: str = STAGES[0]
    epoch: int = 0  # epochs completed in ``stage``
    history: dict[str, list[dict[str, float]]] = field(default_factory=lambda: {s: [] for s in STAGES})
    best: dict[str, Any] = field(default_factory=dict)  # per stage: epoch, value, state dict
    seconds: dict[str, float] = field(default_factory=lambda: {"setup": 0.0, **{s: 0.0 for s in STAGES}})
    model: dict[str, torch.Tensor] | None = None
    optimizer: dict[str, Any] | None = None


def _initial_weights(config: PretrainConfig) -> tuple[dict[str, torch.Tensor], dict[str, Any]]:
    """The weights of ``config.init_from`` and a description of it (path, digest, what made it)."""
    path = Path(config.init_from)
    path = path if path.is_absolute() else REPO_DIR / path  # stored repo-relative
    loaded = load_separator(path, expected_config=config.model, expected_stft=config.train_data.env.stft,
                            expected_classes=list(TARGET_CATEGORIES))
    about = {"path": config.init_from, "sha256": hashlib.sha256(path.read_bytes()).hexdigest()[:16],
             "command": loaded.metadata.get("command"), "observations_seen": loaded.metadata.get("observations_seen")}
    return loaded.separator.state_dict(), about


def state_path(out: Path) -> Path:
    return out.with_name(f"{out.stem}.state.pt")


def _save_state(path: Path, config: PretrainConfig, state: _State) -> None:
    tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
    torch.save({"version": STATE_VERSION, "config": config.result_fields(), **dataclasses.asdict(state)}, tmp)
    os.replace(tmp, path)


def _load_state(path: Path, config: PretrainConfig) -> _State:
    try:
        payload = torch.load(path, map_location="cpu", weights_only=False)
    except (OSError, RuntimeError, EOFError) as exc:
        raise CheckpointError(f"training state {path} is unreadable ({exc}): delete it to start afresh") from exc
    if payload.get("version") != STATE_VERSION or payload.get("config") != config.result_fields():
        raise CheckpointError(f"training state {path} belongs to another configuration: delete it (or pass "
                              f"--fresh) to start afresh, or rerun with the settings it was made with")
    return _State(**{f.name: payload[f.name] for f in dataclasses.fields(_State)})


# --------------------------------------------------------------------------- losses and scores


def _stage1_losses(separator: Separator, mixture: torch.Tensor, share: torch.Tensor, monaural: torch.Tensor,
                   classes: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """L1 of f^B's binaural and f^M's monaural magnitude."""
    _, binaural = separator.separate_binaural(mixture, classes)
    estimate = separator.predict_monaural(binaural.detach(), classes)
    return F.l1_loss(binaural, share), F.l1_loss(estimate, monaural)


def _refine_sequences(separator: Separator, estimates: torch.Tensor) -> torch.Tensor:
    """Run f^R along sequences (B, T, S', H, W): memory reset at step 0, then carried. -> (B, T, ...)."""
    memory, refined = None, []
    for step in range(estimates.shape[1]):
        memory = separator.refine(estimates[:, step], memory)
        refined.append(memory)
    return torch.stack(refined, dim=1)


@torch.no_grad()
def _monaural_estimates(separator: Separator, batch: SeparatorBatch) -> torch.Tensor:
    """Frozen f^B -> f^M estimates of every observation of a batch -> (B, T, S', H, W)."""
    mixture, _, _, classes = batch.observations()
    _, binaural = separator.separate_binaural(mixture, classes)
    estimate = separator.predict_monaural(binaural, classes)
    return estimate.reshape(*batch.mixture.shape[:2], *estimate.shape[1:])


def _refiner_loss(separator: Separator, batch: SeparatorBatch) -> torch.Tensor:
    refined = _refine_sequences(separator, _monaural_estimates(separator, batch))
    return F.l1_loss(refined, batch.monaural[:, None].expand_as(refined))


@torch.no_grad()
def evaluate_stage1(separator: Separator, batches: Sequence[SeparatorBatch]) -> dict[str, float]:
    """Mean L1 of f^B and f^M over every observation, and f^B's two references: the identity mask
    (the mixture itself) and the ideal mask (min(|share|, |mixture|), i.e. |share|/|mixture| capped at 1)."""
    separator.eval()
    totals, count = np.zeros(4), 0
    for batch in batches:
        mixture, share, monaural, classes = batch.observations()
        n = len(mixture)
        losses = [*_stage1_losses(separator, mixture, share, monaural, classes), F.l1_loss(mixture, share),
                  F.l1_loss(torch.minimum(share, mixture), share)]
        totals, count = totals + np.array([float(x) for x in losses]) * n, count + n
    names = ("binaural_l1", "monaural_l1", "identity_mask_binaural_l1", "ideal_mask_binaural_l1")
    return dict(zip(names, (float(v) for v in totals / count)))


@torch.no_grad()
def evaluate_refiner(separator: Separator, batches: Sequence[SeparatorBatch]) -> dict[str, float]:
    """Refined and unrefined (f^M only) L1 to the monaural target, over all steps and at the first and last step."""
    separator.eval()
    per_step, unrefined, count = 0.0, 0.0, 0
    for batch in batches:
        estimates = _monaural_estimates(separator, batch)
        target = batch.monaural[:, None]
        refined = _refine_sequences(separator, estimates)
        n = len(estimates)
        per_step = per_step + (refined - target).abs().mean(dim=(0, 2, 3, 4)) * n
        unrefined, count = unrefined + float((estimates - target).abs().mean()) * n, count + n
    per_step = per_step / count
    return {"refined_l1": float(per_step.mean()), "refined_l1_first": float(per_step[0]),
            "refined_l1_last": float(per_step[-1]), "unrefined_l1": unrefined / count}


# --------------------------------------------------------------------------- the run


def plot_losses(path: Path, history: dict[str, list[dict[str, float]]]) -> Path:
    """Loss curves of both stages (matplotlib Agg) -> PNG."""
    fig, (left, right) = two_panels((11, 4))
    stage1, stage2 = history["stage1"], history["stage2"]
    epochs = [h["epoch"] for h in stage1]
    for key, style in (("train_binaural_l1", "C0--"), ("val_binaural_l1", "C0-"),
                       ("val_identity_mask_binaural_l1", "C0:"), ("val_ideal_mask_binaural_l1", "C0-."),
                       ("train_monaural_l1", "C1--"), ("val_monaural_l1", "C1-")):
        left.plot(epochs, [h[key] for h in stage1], style, marker="o", ms=3, label=key.replace("_", " "))
    left.set(title="stage 1: f^B (binaural) and f^M (monaural)", xlabel="epoch", ylabel="L1 magnitude")
    epochs = [h["epoch"] for h in stage2]
    for key, style in (("train_refined_l1", "C2--"), ("val_refined_l1", "C2-"),
                       ("val_refined_l1_last", "C3-"), ("val_unrefined_l1", "k:")):
        right.plot(epochs, [h[key] for h in stage2], style, marker="o", ms=3, label=key.replace("_", " "))
    right.set(title="stage 2: f^R (val: unheard sounds)", xlabel="epoch", ylabel="L1 magnitude")
    return save_panels(fig, (left, right), path)


EpochHook = Callable[[str, dict[str, float]], None]


def _print_epoch(stage: str, record: dict[str, float]) -> None:
    tqdm.write(f"{stage} epoch {record['epoch']}: " + ", ".join(
        f"{k} {v:.4f}" for k, v in record.items() if k != "epoch"))


def _on(batch: SeparatorBatch, device: torch.device) -> SeparatorBatch:
    """The batch's tensors on ``device`` (the batch itself on the CPU)."""
    if device.type == "cpu":
        return batch
    return batch._replace(**{name: getattr(batch, name).to(device, non_blocking=True)
                             for name in batch._fields if name != "index"})


def _batches(config: PretrainConfig, stream: StreamConfig, library: SoundLibrary, start: int, stop: int,
             rir_cache_dir: Path | None, device: torch.device) -> Iterator[SeparatorBatch]:
    """Batches start..stop-1 of a stream, rendered by the configured worker processes, checked in
    order, on ``device``."""
    loader = DataLoader(SeparatorStream(BatchSource(stream, library, rir_cache_dir=rir_cache_dir), start, stop),
                        batch_size=None, num_workers=config.workers, prefetch_factor=4 if config.workers else None,
                        pin_memory=device.type == "cuda")
    for expected, batch in enumerate(loader, start):
        if batch.index != expected:
            raise RuntimeError(f"data loader gave batch {batch.index}, expected {expected}")
        yield _on(batch, device)


def _train_stage(stage: str, config: PretrainConfig, state: _State, separator: Separator,
                 parameters: list[torch.nn.Parameter], modules: list[torch.nn.Module], *,
                 stream: StreamConfig, epochs: int, batches_per_epoch: int,
                 loss: Callable[[SeparatorBatch], tuple[torch.Tensor, dict[str, float]]],
                 validate: Callable[[], dict[str, float]], select: str, library: SoundLibrary,
                 save: Callable[[], None], on_epoch: EpochHook, progress: bool,
                 rir_cache_dir: Path | None, lr_at: Callable[[int], float] | None = None) -> None:
    """Epochs of one stage from ``state`` on; keeps the best validation ``select`` weights in ``state``.
    ``lr_at(i)``: the learning rate of the stage's batch i (default: ``config.lr`` throughout)."""
    optimizer = torch.optim.Adam(parameters, lr=config.lr)
    if state.stage == stage and state.optimizer is not None:
        optimizer.load_state_dict(state.optimizer)
    first = state.epoch + 1
    batches = _batches(config, stream, library, state.epoch * batches_per_epoch, epochs * batches_per_epoch,
                       rir_cache_dir, next(separator.parameters()).device)
    for epoch in range(first, epochs + 1):
        started = time.perf_counter()
        for module in modules:
            module.train()
        sums: dict[str, float] = {}
        bar = tqdm(range(batches_per_epoch), disable=not progress, desc=f"{stage} epoch {epoch}/{epochs}",
                   unit="batch", leave=False)
        for step in bar:
            if lr_at is not None:
                for group in optimizer.param_groups:
                    group["lr"] = lr_at((epoch - 1) * batches_per_epoch + step)
            total, parts = loss(next(batches))
            optimizer.zero_grad()
            total.backward()
            optimizer.step()
            for k, v in parts.items():
                sums[k] = sums.get(k, 0.0) + v
            bar.set_postfix({k: f"{v:.3f}" for k, v in parts.items()})
        scores = validate()
        record = {"epoch": epoch, **{f"train_{k}": v / batches_per_epoch for k, v in sums.items()},
                  **{f"val_{k}": v for k, v in scores.items()}}
        state.history[stage].append(record)
        if stage not in state.best or scores[select] < state.best[stage]["value"]:
            state.best[stage] = {"epoch": epoch, "value": scores[select],
                                 "state": copy.deepcopy(separator.state_dict())}
        state.stage, state.epoch = stage, epoch
        state.model, state.optimizer = separator.state_dict(), optimizer.state_dict()
        state.seconds[stage] += time.perf_counter() - started
        save()
        on_epoch(stage, record)


def pretrain(config: PretrainConfig, library: SoundLibrary, *, out: Path, command: str | None = None,
             progress: bool = True, fresh: bool = False, rir_workers: int = 2, rir_cache_dir: Path | None = None,
             on_epoch: EpochHook = _print_epoch) -> PretrainResult:
    """Train both stages (resuming from ``<out stem>.state.pt`` unless ``fresh``), then write the
    checkpoint, its metadata JSON and the loss curve PNG."""
    out = Path(out)
    started = time.perf_counter()
    torch.set_num_threads(config.threads)
    torch.manual_seed(config.seed)
    separator = Separator(config.model)  # built (and seeded) on the CPU whatever the device
    device = config.torch_device()
    state_file = state_path(out)
    state = _load_state(state_file, config) if state_file.exists() and not fresh else _State()
    resumed = {"stage": state.stage, "epoch": state.epoch} if state.model is not None else None
    initialised_from = None
    if config.init_from:
        weights, initialised_from = _initial_weights(config)
        if state.model is None:
            separator.load_state_dict(weights)
    if state.model is not None:
        separator.load_state_dict(state.model)
    separator.to(device)
    for stream in (config.train_data, config.refiner_data, config.val_data):
        build_banks(stream, cache_dir=rir_cache_dir, workers=rir_workers, progress=progress)
    val = [_on(batch, device) for batch in fixed_set(BatchSource(config.val_data, library, rir_cache_dir=rir_cache_dir),
                                                       config.val_batches, progress=progress)]
    state.seconds["setup"] += time.perf_counter() - started
    out.parent.mkdir(parents=True, exist_ok=True)
    common = dict(library=library, save=lambda: _save_state(state_file, config, state), on_epoch=on_epoch,
                  progress=progress, rir_cache_dir=rir_cache_dir)

    def stage1_loss(batch: SeparatorBatch) -> tuple[torch.Tensor, dict[str, float]]:
        loss_b, loss_m = _stage1_losses(separator, *batch.observations())
        return loss_b + loss_m, {"binaural_l1": loss_b.item(), "monaural_l1": loss_m.item()}

    def stage2_loss(batch: SeparatorBatch) -> tuple[torch.Tensor, dict[str, float]]:
        loss = _refiner_loss(separator, batch)
        return loss, {"refined_l1": loss.item()}

    frozen = (separator.binaural_separator, separator.monaural_predictor)
    if state.stage == "stage1":
        _train_stage("stage1", config, state, separator,
                     [p for m in frozen for p in m.parameters()], list(frozen),
                     stream=config.train_data, epochs=config.epochs, batches_per_epoch=config.batches_per_epoch,
                     loss=stage1_loss, validate=lambda: evaluate_stage1(separator, val), select="monaural_l1",
                     lr_at=config.stage1_lr, **common)
        # Stage 2 starts from the best stage-1 weights (its refiner still the untrained one).
        separator.load_state_dict(state.best["stage1"]["state"])
        state.stage, state.epoch, state.optimizer = "stage2", 0, None
    for module in frozen:
        module.eval().requires_grad_(False)
    _train_stage("stage2", config, state, separator, list(separator.refiner.parameters()), [separator.refiner],
                 stream=config.refiner_data, epochs=config.refiner_epochs,
                 batches_per_epoch=config.refiner_batches_per_epoch, loss=stage2_loss,
                 validate=lambda: evaluate_refiner(separator, val), select="refined_l1", **common)
    separator.load_state_dict(state.best["stage2"]["state"])
    separator.cpu().eval().requires_grad_(True)  # checkpoints hold CPU tensors

    history = state.history
    best1, best2 = state.best["stage1"]["epoch"], state.best["stage2"]["epoch"]
    samples = {"stage1": len(history["stage1"]) * config.batches_per_epoch * config.train_data.batch_size,
               "stage2": len(history["stage2"]) * config.refiner_batches_per_epoch * config.refiner_data.batch_size
               * config.refiner_data.steps}
    seconds = {k: round(v, 1) for k, v in state.seconds.items()}
    metadata = {
        "command": command or "pretrain()",
        "config": {k: v for k, v in dataclasses.asdict(config).items() if k not in ("model",)},
        "epochs_run": {stage: len(history[stage]) for stage in STAGES},
        "parameters": count_parameters(separator),
        # What m2h-separate scales recordings to: the unaugmented conditions the separator is scored in.
        "mixture_power": float(torch.cat([b.power.flatten() for b in val]).mean()),
        "library_fingerprint": library.fingerprint,
        "observations_seen": samples,
        "validation": {"sequences": config.val_batches * config.val_data.batch_size, "steps": config.val_data.steps},
        "best_epoch": best1, "best_refiner_epoch": best2,
        "final": {**{k: v for k, v in history["stage1"][best1 - 1].items() if k != "epoch"},
                  **{k: v for k, v in history["stage2"][best2 - 1].items() if k != "epoch"}},
        "history": history,
        "resumed_from": resumed,
        "initialised_from": initialised_from,
        "wall_seconds": {**seconds, "total": round(sum(state.seconds.values()), 1)},
        "observations_per_second": {s: round(samples[s] / max(state.seconds[s], 1e-9), 1) for s in STAGES},
        "machine": {**machine_description(), "device": str(device)},
    }
    save_separator(out, separator, classes=list(TARGET_CATEGORIES), stft_config=config.train_data.env.stft,
                   metadata=metadata, metadata_json=True)
    plot_losses(out.with_name(f"{out.stem}_loss.png"), history)
    state_file.unlink(missing_ok=True)
    return PretrainResult(separator, out, metadata)


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(description="Pretrain the passive separator (f^B, f^M, f^R) on simulator data.")
    defaults = PretrainConfig()
    parser.add_argument("--preset", choices=PRESET_NAMES, default="compact", help="model size (default compact)")
    parser.add_argument("--backbone", choices=BACKBONES, default="unet",
                        help="f^B / f^M network (default unet; mmdensenet: experiment 5, its own compact width)")
    parser.add_argument("--seed", type=int, default=0, help="weights")
    parser.add_argument("--data-seed", type=int, default=0, help="training streams (validation set: fixed)")
    parser.add_argument("--out", type=Path, default=PRETRAINED_SEPARATOR_CHECKPOINT, help="checkpoint path")
    parser.add_argument("--epochs", type=int, default=defaults.epochs, help="stage 1 (f^B + f^M) epochs")
    parser.add_argument("--batches-per-epoch", type=int, default=defaults.batches_per_epoch,
                        help=f"stage 1 batches of {defaults.train_data.batch_size} observations per epoch")
    parser.add_argument("--refiner-epochs", type=int, default=defaults.refiner_epochs, help="stage 2 (f^R) epochs")
    parser.add_argument("--refiner-batches-per-epoch", type=int, default=defaults.refiner_batches_per_epoch,
                        help=f"stage 2 batches of {defaults.refiner_data.batch_size} sequences of "
                             f"{defaults.refiner_data.steps} observations per epoch")
    parser.add_argument("--train-scenes", type=int, default=None,
                        help="draw from the first N training scenes only (default: all)")
    parser.add_argument("--source-nodes", type=int, default=None,
                        help="place sources on this many nodes per scene only (fewer RIR source nodes to "
                             "simulate; default: every node)")
    parser.add_argument("--eq-db", type=float, default=0.0,
                        help="spectral colouring augmentation of each source, at most this many dB "
                             "(training streams; default 0: none)")
    parser.add_argument("--speed-min", type=float, default=1.0,
                        help="slow-down augmentation: each training sequence played at a speed uniform in "
                             "[SPEED_MIN, 1] (lower pitch, longer room; default 1: none)")
    parser.add_argument("--head", default=KEMAR, help=HEAD_HELP)
    parser.add_argument("--acoustics-backend", default="project", choices=BACKENDS, help=BACKEND_HELP)
    parser.add_argument("--init-from", type=Path, default=None,
                        help="start stage 1 from this separator checkpoint's weights (fine-tuning)")
    parser.add_argument("--final-lr", type=float, default=None,
                        help="anneal stage 1's learning rate to this along a cosine (default: constant)")
    parser.add_argument("--threads", type=int, default=defaults.threads, help="torch threads of the trainer")
    parser.add_argument("--workers", type=int, default=defaults.workers, help="data loader processes")
    parser.add_argument("--device", default=defaults.device, choices=DEVICES,
                        help="where the networks train (auto: CUDA when present)")
    parser.add_argument("--fresh", action="store_true", help="ignore a saved training state and start afresh")
    return parser


def config_from_args(args: argparse.Namespace) -> PretrainConfig:
    """The run :func:`main` makes of ``build_parser()``'s arguments."""
    model = dataclasses.replace(SeparatorConfig.preset(args.preset), backbone=args.backbone)
    # every stream hears the head
    env = EnvConfig(camera=False, acoustics=AcousticsConfig(head=args.head, backend=args.acoustics_backend))
    return PretrainConfig(model=model, seed=args.seed, epochs=args.epochs,
                      batches_per_epoch=args.batches_per_epoch, refiner_epochs=args.refiner_epochs,
                      refiner_batches_per_epoch=args.refiner_batches_per_epoch, threads=args.threads,
                      workers=args.workers, device=args.device, final_lr=args.final_lr,
                      init_from=repo_relative(args.init_from) if args.init_from else "",
                      train_data=dataclasses.replace(
                          StreamConfig.training(seed=args.data_seed, scenes=args.train_scenes,
                                                source_nodes=args.source_nodes, eq_db=args.eq_db,
                                                speed_min=args.speed_min), env=env),
                      refiner_data=dataclasses.replace(_stage2_stream(), seed=args.data_seed, eq_db=args.eq_db,
                                                       speed_min=args.speed_min, env=env,
                                                       scenes=args.train_scenes, source_nodes=args.source_nodes),
                      val_data=dataclasses.replace(StreamConfig.validation(source_nodes=args.source_nodes), env=env))


@reports_errors("train_separator")
def main(argv: Sequence[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    config = config_from_args(args)
    command = shlex.join([Path(sys.argv[0]).name, *(sys.argv[1:] if argv is None else argv)])
    result = pretrain(config, SoundLibrary.load(), out=args.out, command=command, fresh=args.fresh)
    final, wall = result.metadata["final"], result.metadata["wall_seconds"]
    print(f"wrote {repo_relative(result.checkpoint)} ({result.checkpoint.stat().st_size / 2**20:.1f} MiB) in "
          f"{wall['total']:.0f} s; val monaural L1 {final['val_monaural_l1']:.4f}, refined L1 "
          f"{final['val_refined_l1']:.4f}, f^B {final['val_binaural_l1']:.4f} vs identity mask "
          f"{final['val_identity_mask_binaural_l1']:.4f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
