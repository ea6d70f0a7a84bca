"""Pretrain the passive separator (f^B, f^M, then f^R) on simulator recordings; one readable loop.

    python -m m2h_ros.training.pretrain_separator [--preset compact] [--seed 0] [--out PATH]

Data (``separator_data``): sequences recorded in the train scenes with heard sounds (training) and
in the val scenes with unheard sounds (validation), built and cached on first use.

Stage 1 (f^B + f^M, Adam 5e-4 as the seed says), one pass per batch of single observations:
  * f^B predicts a ratio mask on the mixture magnitude; loss L1(mask * |mixture|, |target share|),
    where the target's share of the mixture is its binaural render / the number of sources (the
    mixture is the sum of the renders divided by that number, so this is what a mask can reach);
  * f^M maps f^B's separated binaural magnitude to the target's dry monaural magnitude; loss L1.
    f^M's input is f^B's output *detached*: f^M learns on what f^B really produces (as at inference)
    while its loss does not pull f^B away from its own binaural target.
  Validation (unheard sounds) after every epoch; the weights with the best validation f^M loss are kept.
Stage 2 (f^R): f^B and f^M frozen (eval mode); their estimates for every recorded step are computed
once; the refiner runs along each sequence with its memory reset at the episode's first step and
the previous refined estimate carried over (backpropagation through the whole sequence), loss L1 of
every step's refined estimate to the ground-truth monaural magnitude. Best validation epoch kept.

Outputs: the checkpoint (``save_separator``: model args, STFT, classes, metadata), ``<stem>.json``
(metadata: data sizes, epochs, wall times, machine, losses, command) and ``<stem>_loss.png``.
"""

from __future__ import annotations

import argparse
import copy
import json
import os
import platform
import shlex
import sys
import time
from collections.abc import Sequence
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
from tqdm import tqdm  # noqa: E402

from m2h_ros.core.audio.stft import to_slices  # noqa: E402
from m2h_ros.core.sounds.library import TARGET_CATEGORIES, SoundLibrary  # noqa: E402
from m2h_ros.errors import ConfigError  # noqa: E402
from m2h_ros.models.checkpoint import DEFAULT_SEPARATOR_CHECKPOINT, save_separator  # noqa: E402
from m2h_ros.models.separator import PRESET_NAMES, Separator, SeparatorConfig, count_parameters  # noqa: E402
from m2h_ros.training.separator_data import SeparatorDataConfig, SeparatorDataset, separator_dataset  # noqa: E402


def _compact() -> SeparatorConfig:
    return SeparatorConfig.preset("compact")


@dataclass(frozen=True)
class PretrainConfig:
    """Hyperparameters of one pretraining run."""

    model: SeparatorConfig = field(default_factory=_compact)
    seed: int = 0  # weights, batch order
    lr: float = 5e-4  # Adam, both stages (the seed's pretraining rate)
    batch_size: int = 16  # observations per f^B/f^M batch
    epochs: int = 8  # stage 1 passes over the training observations
    refiner_batch_size: int = 8  # sequences per f^R batch
    refiner_epochs: int = 15  # stage 2 passes over the training sequences
    threads: int = 2  # torch intra-op threads
    max_batches: int | None = None  # cap on batches per epoch (smoke runs, tests)
    train_data: SeparatorDataConfig = field(default_factory=SeparatorDataConfig.training)
    val_data: SeparatorDataConfig = field(default_factory=SeparatorDataConfig.validation)

    def __post_init__(self) -> None:
        if not isinstance(self.model, SeparatorConfig):
            raise ConfigError(f"PretrainConfig.model must be a SeparatorConfig, got {type(self.model).__name__}")
        for name, low in (("seed", 0), ("batch_size", 2), ("epochs", 1), ("refiner_batch_size", 2),
                          ("refiner_epochs", 1), ("threads", 1)):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, int) or value < low:
                raise ConfigError(f"PretrainConfig.{name} must be an int >= {low}, got {value!r}")
        if not (isinstance(self.lr, float) and 0 < self.lr < 1):
            raise ConfigError(f"PretrainConfig.lr must be a float in (0, 1), got {self.lr!r}")
        if self.max_batches is not None and (isinstance(self.max_batches, bool) or self.max_batches < 1):
            raise ConfigError(f"PretrainConfig.max_batches must be None or >= 1, got {self.max_batches!r}")
        if self.train_data.env.stft != self.val_data.env.stft:
            raise ConfigError("PretrainConfig: train_data and val_data use different STFT settings")
        self.model.check_stft(self.train_data.env.stft)


@dataclass
class PretrainResult:
    separator: Separator
    checkpoint: Path
    metadata: dict[str, Any]


# --------------------------------------------------------------------------- batches


@dataclass(frozen=True)
class _Tensors:
    """A dataset as torch tensors in the sliced layout, float16 as stored (converted per batch)."""

    mixture_logmag: torch.Tensor  # (S, T, 2S', H, W) log(1 + |mixture|)
    target_binaural: torch.Tensor  # (S, T, 2S', H, W) |target alone as heard|
    target_monaural: torch.Tensor  # (S, S', H, W) |dry target|
    class_index: torch.Tensor  # (S,)
    n_sources: torch.Tensor  # (S,)

    @classmethod
    def of(cls, data: SeparatorDataset, n_slices: int) -> _Tensors:
        def sliced(array: np.ndarray) -> torch.Tensor:
            return torch.from_numpy(np.ascontiguousarray(to_slices(array, n_slices=n_slices)))

        return cls(sliced(data.mixture_logmag), sliced(data.target_binaural),
                   sliced(np.asarray(data.target_monaural)[:, None]),
                   torch.from_numpy(np.asarray(data.class_index, dtype=np.int64)),
                   torch.from_numpy(np.asarray(data.n_sources, dtype=np.int64)))

    @property
    def steps(self) -> int:
        return self.mixture_logmag.shape[1]

    def observations(self, flat: np.ndarray) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor]:
        """(|mixture|, target's share of the mixture, monaural target, class) of observations
        ``flat`` (indices into S * T); the share is the target's render / the number of sources."""
        seq, step = (torch.from_numpy(a) for a in np.divmod(flat, self.steps))
        share = self.target_binaural[seq, step].float() / self.n_sources[seq].reshape(-1, 1, 1, 1)
        return (torch.expm1(self.mixture_logmag[seq, step].float()), share,
                self.target_monaural[seq].float(), self.class_index[seq])


def _batches(n: int, size: int, rng: np.random.Generator | None, limit: int | None) -> list[np.ndarray]:
    """Index batches over n items (shuffled when rng is given); a last batch of 1 is dropped (BatchNorm)."""
    order = rng.permutation(n) if rng is not None else np.arange(n)
    batches = [order[i: i + size] for i in range(0, n, size)]
    batches = [b for b in batches if len(b) > 1]
    return batches[:limit] if limit else batches


def _stage1_losses(separator: Separator, data: _Tensors, flat: np.ndarray) -> tuple[torch.Tensor, torch.Tensor]:
    """L1 of f^B's binaural and f^M's monaural magnitude for observations ``flat`` (indices into S*T)."""
    mixture, share, monaural_target, classes = data.observations(flat)
    _, binaural = separator.separate_binaural(mixture, classes)
    monaural = separator.predict_monaural(binaural.detach(), classes)
    return F.l1_loss(binaural, share), F.l1_loss(monaural, monaural_target)


def _refine_sequences(separator: Separator, estimates: torch.Tensor) -> torch.Tensor:
    """Run f^R along sequences (B, T, S', H, W): memory reset at step 0, then carried. -> (B, T, ...)."""
    memory, refined = None, []
    for step in range(estimates.shape[1]):
        memory = separator.refine(estimates[:, step], memory)
        refined.append(memory)
    return torch.stack(refined, dim=1)


@torch.no_grad()
def _monaural_estimates(separator: Separator, data: _Tensors, batch_size: int) -> torch.Tensor:
    """f^M estimates (S, T, S', H, W) of every recorded step (call with f^B, f^M in eval mode)."""
    s, t = data.mixture_logmag.shape[:2]
    out = torch.empty((s * t, *data.target_monaural.shape[1:]))
    for start in range(0, s * t, batch_size):
        flat = np.arange(start, min(start + batch_size, s * t))
        mixture, _, _, classes = data.observations(flat)
        _, binaural = separator.separate_binaural(mixture, classes)
        out[flat] = separator.predict_monaural(binaural, classes)
    return out.reshape(s, t, *out.shape[1:])


@torch.no_grad()
def evaluate_stage1(separator: Separator, data: _Tensors, batch_size: int) -> dict[str, float]:
    separator.eval()
    batches = _batches(data.mixture_logmag.shape[0] * data.steps, batch_size, None, None)
    totals = np.zeros(2)
    for flat in batches:
        totals += [float(x) * len(flat) for x in _stage1_losses(separator, data, flat)]
    used = sum(len(b) for b in batches)
    return {"binaural_l1": float(totals[0] / used), "monaural_l1": float(totals[1] / used)}


@torch.no_grad()
def evaluate_refiner(separator: Separator, estimates: torch.Tensor, targets: torch.Tensor) -> dict[str, float]:
    """Refined and unrefined (f^M only) L1 to the monaural target, over all steps and at the first and last step."""
    separator.eval()
    refined = _refine_sequences(separator, estimates)
    per_step = (refined - targets[:, None]).abs().mean(dim=(0, 2, 3, 4))
    return {"refined_l1": float(per_step.mean()), "refined_l1_first": float(per_step[0]),
            "refined_l1_last": float(per_step[-1]),
            "unrefined_l1": float((estimates - targets[:, None]).abs().mean())}


# --------------------------------------------------------------------------- the run


def _machine() -> dict[str, Any]:
    model = platform.processor() or platform.machine()
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                model = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    return {"cpu_model": model, "cpu_count": os.cpu_count(), "platform": platform.platform(),
            "python": platform.python_version(), "torch": str(torch.__version__)}


def plot_losses(path: Path, history: dict[str, list[dict[str, float]]]) -> Path:
    """Loss curves of both stages (matplotlib Agg) -> PNG."""
    import matplotlib  # noqa: PLC0415

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt  # noqa: PLC0415

    fig, (left, right) = plt.subplots(1, 2, figsize=(11, 4))
    stage1, stage2 = history["stage1"], history["stage2"]
    epochs = [h["epoch"] for h in stage1]
    for key, style in (("train_binaural_l1", "C0--"), ("val_binaural_l1", "C0-"),
                       ("train_monaural_l1", "C1--"), ("val_monaural_l1", "C1-")):
        left.plot(epochs, [h[key] for h in stage1], style, marker="o", ms=3, label=key.replace("_", " "))
    left.set(title="stage 1: f^B (binaural) and f^M (monaural)", xlabel="epoch", ylabel="L1 magnitude")
    epochs = [h["epoch"] for h in stage2]
    for key, style in (("train_refined_l1", "C2--"), ("val_refined_l1", "C2-"),
                       ("val_refined_l1_last", "C3-"), ("val_unrefined_l1", "k:")):
        right.plot(epochs, [h[key] for h in stage2], style, marker="o", ms=3, label=key.replace("_", " "))
    right.set(title="stage 2: f^R (val: unheard sounds)", xlabel="epoch", ylabel="L1 magnitude")
    for ax in (left, right):
        ax.grid(alpha=0.3)
        ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def pretrain(config: PretrainConfig, library: SoundLibrary, *, out: Path, command: str | None = None,
             progress: bool = True, n_envs: int = 16, rir_workers: int = 2) -> PretrainResult:
    """Build/load the data, train both stages, write checkpoint + metadata JSON + loss curve PNG."""
    started = time.perf_counter()
    torch.set_num_threads(config.threads)
    torch.manual_seed(config.seed)
    rng = np.random.default_rng(config.seed)
    stft_config = config.train_data.env.stft
    n_slices = config.model.n_freq_slices

    train_set = separator_dataset(config.train_data, library, n_envs=n_envs, rir_workers=rir_workers,
                                  progress=progress, mmap=False)
    val_set = separator_dataset(config.val_data, library, n_envs=n_envs, rir_workers=rir_workers,
                                progress=progress, mmap=False)
    data_seconds = time.perf_counter() - started
    train, val = _Tensors.of(train_set, n_slices), _Tensors.of(val_set, n_slices)
    separator = Separator(config.model)
    history: dict[str, list[dict[str, float]]] = {"stage1": [], "stage2": []}

    # Stage 1: f^B and f^M together (f^M fed f^B's detached output); keep the best val f^M loss.
    stage1_params = [*separator.binaural_separator.parameters(), *separator.monaural_predictor.parameters()]
    optimizer = torch.optim.Adam(stage1_params, lr=config.lr)
    best_val, best_state, best_epoch = float("inf"), None, 0
    n_train = train.mixture_logmag.shape[0] * train.steps
    for epoch in range(1, config.epochs + 1):
        separator.train()
        sums, count = np.zeros(2), 0
        bar = tqdm(_batches(n_train, config.batch_size, rng, config.max_batches), disable=not progress,
                   desc=f"f^B+f^M epoch {epoch}/{config.epochs}", unit="batch", leave=False)
        for flat in bar:
            loss_b, loss_m = _stage1_losses(separator, train, flat)
            optimizer.zero_grad()
            (loss_b + loss_m).backward()
            optimizer.step()
            losses = np.array([loss_b.item(), loss_m.item()])
            sums, count = sums + losses * len(flat), count + len(flat)
            bar.set_postfix(binaural=f"{losses[0]:.3f}", monaural=f"{losses[1]:.3f}")
        scores = evaluate_stage1(separator, val, config.batch_size * 2)
        history["stage1"].append({"epoch": epoch, "train_binaural_l1": float(sums[0] / count),
                                  "train_monaural_l1": float(sums[1] / count), "val_binaural_l1": scores["binaural_l1"],
                                  "val_monaural_l1": scores["monaural_l1"]})
        if scores["monaural_l1"] < best_val:
            best_val, best_epoch = scores["monaural_l1"], epoch
            best_state = copy.deepcopy(separator.state_dict())
        if progress:
            tqdm.write(f"stage 1 epoch {epoch}: " + ", ".join(f"{k} {v:.4f}" for k, v in history["stage1"][-1].items()
                                                             if k != "epoch"))
    separator.load_state_dict(best_state)
    stage1_seconds = time.perf_counter() - started - data_seconds

    # Stage 2: f^R on sequences of the frozen f^M's estimates; memory reset at each episode start.
    for module in (separator.binaural_separator, separator.monaural_predictor):
        module.eval().requires_grad_(False)
    train_estimates = _monaural_estimates(separator, train, config.batch_size * 2)
    val_estimates = _monaural_estimates(separator, val, config.batch_size * 2)
    optimizer = torch.optim.Adam(separator.refiner.parameters(), lr=config.lr)
    best_refined, best_refiner, best_refiner_epoch = float("inf"), None, 0
    for epoch in range(1, config.refiner_epochs + 1):
        separator.refiner.train()
        total, count = 0.0, 0
        bar = tqdm(_batches(train_estimates.shape[0], config.refiner_batch_size, rng, config.max_batches),
                   disable=not progress, desc=f"f^R epoch {epoch}/{config.refiner_epochs}", unit="batch",
                   leave=False)
        for seqs in bar:
            index = torch.from_numpy(seqs)
            refined = _refine_sequences(separator, train_estimates[index])
            loss = F.l1_loss(refined, train.target_monaural[index].float()[:, None].expand_as(refined))
            optimizer.zero_grad()
            loss.backward()
            optimizer.step()
            total, count = total + loss.item() * len(seqs), count + len(seqs)
            bar.set_postfix(refined=f"{loss.item():.3f}")
        scores = evaluate_refiner(separator, val_estimates, val.target_monaural.float())
        history["stage2"].append({"epoch": epoch, "train_refined_l1": total / count,
                                  **{f"val_{k}": v for k, v in scores.items()}})
        if scores["refined_l1"] < best_refined:
            best_refined, best_refiner_epoch = scores["refined_l1"], epoch
            best_refiner = copy.deepcopy(separator.refiner.state_dict())
        if progress:
            tqdm.write(f"stage 2 epoch {epoch}: " + ", ".join(f"{k} {v:.4f}" for k, v in history["stage2"][-1].items()
                                                             if k != "epoch"))
    separator.refiner.load_state_dict(best_refiner)
    separator.eval().requires_grad_(True)
    wall = time.perf_counter() - started

    metadata = {
        "command": command or "pretrain()",
        "seed": config.seed, "lr": config.lr, "batch_size": config.batch_size, "epochs": config.epochs,
        "refiner_batch_size": config.refiner_batch_size, "refiner_epochs": config.refiner_epochs,
        "max_batches": config.max_batches, "threads": config.threads,
        "parameters": count_parameters(separator),
        "mixture_power": float(np.mean(train_set.mixture_power)),
        "library_fingerprint": library.fingerprint,
        "data": {name: {"sequences": data.n_sequences, "steps": data.steps, "observations": data.n_samples,
                        "bytes": data.nbytes(), "cache": str(data.path), "config": cfg.to_dict(),
                        "build": {k: data.meta.get(k) for k in ("rir_nodes_simulated", "rir_seconds",
                                                                 "record_seconds")}}
                 for name, data, cfg in (("train", train_set, config.train_data), ("val", val_set, config.val_data))},
        "best_epoch": best_epoch, "best_refiner_epoch": best_refiner_epoch,
        "final": {**{k: v for k, v in history["stage1"][best_epoch - 1].items() if k != "epoch"},
                  **{k: v for k, v in history["stage2"][best_refiner_epoch - 1].items() if k != "epoch"}},
        "history": history,
        "wall_seconds": {"data": round(data_seconds, 1), "stage1": round(stage1_seconds, 1),
                         "stage2": round(wall - data_seconds - stage1_seconds, 1), "total": round(wall, 1)},
        "machine": _machine(),
    }
    out = Path(out)
    save_separator(out, separator, classes=list(TARGET_CATEGORIES), stft_config=stft_config, metadata=metadata)
    out.with_suffix(".json").write_text(json.dumps(metadata, indent=1) + "\n")
    plot_losses(out.with_name(f"{out.stem}_loss.png"), history)
    return PretrainResult(separator, out, metadata)


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(description="Pretrain the passive separator (f^B, f^M, f^R) on simulator data.")
    parser.add_argument("--preset", choices=PRESET_NAMES, default="compact", help="model size (default compact)")
    parser.add_argument("--seed", type=int, default=0, help="weights and batch order")
    parser.add_argument("--data-seed", type=int, default=0, help="episodes, random policy and clip variants")
    parser.add_argument("--out", type=Path, default=DEFAULT_SEPARATOR_CHECKPOINT, help="checkpoint path")
    defaults = PretrainConfig()
    parser.add_argument("--epochs", type=int, default=defaults.epochs, help="stage 1 (f^B + f^M) epochs")
    parser.add_argument("--refiner-epochs", type=int, default=defaults.refiner_epochs, help="stage 2 (f^R) epochs")
    parser.add_argument("--batch-size", type=int, default=defaults.batch_size)
    parser.add_argument("--threads", type=int, default=defaults.threads, help="torch threads")
    parser.add_argument("--max-batches", type=int, default=None, help="cap batches per epoch (smoke runs)")
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    config = PretrainConfig(model=SeparatorConfig.preset(args.preset), seed=args.seed, epochs=args.epochs,
                            refiner_epochs=args.refiner_epochs, batch_size=args.batch_size, threads=args.threads,
                            max_batches=args.max_batches,
                            train_data=SeparatorDataConfig.training(seed=args.data_seed),
                            val_data=SeparatorDataConfig.validation(seed=args.data_seed))
    command = shlex.join([Path(sys.argv[0]).name, *(sys.argv[1:] if argv is None else argv)])
    result = pretrain(config, SoundLibrary.load(), out=args.out, command=command)
    final, wall = result.metadata["final"], result.metadata["wall_seconds"]
    print(f"wrote {result.checkpoint} ({result.checkpoint.stat().st_size / 2**20:.1f} MiB) in {wall['total']:.0f} s; "
          f"val monaural L1 {final['val_monaural_l1']:.4f}, refined L1 {final['val_refined_l1']:.4f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
