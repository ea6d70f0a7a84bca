#!/usr/bin/env python3
"""Separator cost on CPU: ms per step of f^B + f^M + f^R, reference and fused, by thread count.

Per preset, at batch 1 with 1 and 2 torch threads:

* ``clip``: the whole per-step path, ``separate_clip`` on a 1 s binaural waveform with the fused model
  (``fuse_for_inference``): STFT, f^B, f^M, f^R and the mixture-phase inverse STFT. Its numpy parts
  are timed too (``stft``, ``rebuild``: one thread whatever torch uses).
* ``step``: the fused networks only; ``reference``: the networks as trained (eager, BatchNorm layers),
  both under ``torch.inference_mode``.
* ``bare unet``: one plain eager U-Net of the same widths (33 -> 32 channels, BatchNorm, eval). A step
  runs two U-Nets plus the refiner, so ``clip / bare unet`` near 2 means no cost beyond two plain
  U-Net forwards; below 2, the fused path beats plain layers.

Then batch 32 (fused and reference), and (compact) a thread sweep over batch sizes next to what
``models.threads.inference_threads`` picks. The fused outputs are checked against the reference (max
error relative to the peak).

The machine is shared, so the candidates of a table are timed in rounds (each round runs every
candidate once: all see the same load) and each gets the median and the minimum wall time of
``--repeats`` rounds (batch 32: a fifth, 3 to 10), and the minimum CPU time. The minimum is the
better estimate of the uncontended cost; at 1 thread the CPU time is the cost least disturbed by
other processes. The load average is printed before and after.

    .venv/bin/python scripts/bench/separator.py [--repeats 60] [--presets compact paper]
        [--backbones unet mmdensenet] [--no-sweep]

``--backbones mmdensenet`` adds the MMDenseNet-style separator (experiment 5); its ``bare unet`` row
is still the compact U-Net, so ``clip / bare unet`` there compares the two backbones.
"""

from __future__ import annotations

import argparse
import os
import tempfile
import time
from collections.abc import Callable
from pathlib import Path

# Idle OpenMP threads sleep instead of spinning (libgomp reads this when torch loads): spinning threads
# are many times slower whenever the 2 cores are shared. Override by setting the variable yourself.
os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")

import numpy as np  # noqa: E402
import torch  # noqa: E402

from m2h_ros.core.audio.stft import DEFAULT_STFT, rebuild_with_phase, stft  # noqa: E402
from m2h_ros.models.checkpoint import save_separator  # noqa: E402
from m2h_ros.models.inference import fuse_for_inference  # noqa: E402
from m2h_ros.models.separator import (  # noqa: E402
    BACKBONES,
    PRESET_NAMES,
    Separator,
    SeparatorConfig,
    count_parameters,
    separate_clip,
)
from m2h_ros.models.threads import inference_threads  # noqa: E402
from m2h_ros.machine import availability_line, load_average  # noqa: E402
from m2h_ros.models.unet import UNet  # noqa: E402

THREADS = (1, 2)
SWEEP_BATCHES = (1, 2, 4, 8, 16, 32)


def timed_rounds(fns: dict[str, Callable[[], object]], repeats: int, *, threads: int | dict[str, int] = 1,
                 warmup: int = 5) -> dict[str, dict[str, float]]:
    """Per candidate: ``median`` and ``min`` wall ms and ``cpu`` (min CPU ms) over ``repeats`` rounds,
    each round running every candidate once; ``threads`` (one count, or one per candidate)."""
    counts = threads if isinstance(threads, dict) else dict.fromkeys(fns, threads)
    for name, fn in fns.items():
        torch.set_num_threads(counts[name])
        for _ in range(warmup):
            fn()
    wall: dict[str, list[float]] = {name: [] for name in fns}
    cpu: dict[str, list[float]] = {name: [] for name in fns}
    for _ in range(repeats):
        for name, fn in fns.items():
            torch.set_num_threads(counts[name])
            start_wall, start_cpu = time.perf_counter(), time.process_time()
            fn()
            wall[name].append(time.perf_counter() - start_wall)
            cpu[name].append(time.process_time() - start_cpu)
    return {name: {"median": 1000.0 * float(np.median(wall[name])), "min": 1000.0 * min(wall[name]),
                   "cpu": 1000.0 * min(cpu[name])} for name in fns}


def with_running_stats(separator: Separator) -> Separator:
    """Non-trivial BatchNorm statistics, as after training (fresh ones fold to the identity)."""
    generator = torch.Generator().manual_seed(1)
    for layer in separator.modules():
        if isinstance(layer, torch.nn.BatchNorm2d):
            for tensor, low, high in ((layer.running_mean, -0.5, 0.5), (layer.running_var, 0.5, 2.0),
                                      (layer.weight.data, 0.5, 1.5), (layer.bias.data, -0.2, 0.2)):
                tensor.copy_(torch.rand(tensor.shape, generator=generator) * (high - low) + low)
    return separator


def network_inputs(config: SeparatorConfig, batch: int) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    height, width = DEFAULT_STFT.slice_shape
    shape = (batch, config.binaural_channels, height, width)
    mixture = (torch.rand(shape) * 10).contiguous(memory_format=torch.channels_last)
    memory = torch.rand(batch, config.monaural_channels, height, width).contiguous(memory_format=torch.channels_last)
    return mixture, torch.zeros(batch, dtype=torch.long), memory


def relative_error(reference: Separator, fused: Separator, config: SeparatorConfig) -> float:
    mixture, classes, memory = network_inputs(config, 4)
    with torch.inference_mode():
        pairs = zip(reference(mixture, classes, memory), fused(mixture, classes, memory), strict=True)
        return max(float((a - b).abs().max() / a.abs().max()) for a, b in pairs)


def bench_config(config: SeparatorConfig, repeats: int) -> dict:
    """{"params", "checkpoint_mb", "fused_rel_error", "numpy": {...}, (batch, threads): {candidate: figures}}."""
    torch.manual_seed(0)
    name = config.backbone
    reference = with_running_stats(Separator(config)).eval()
    fused = fuse_for_inference(reference)
    bare = UNet(config.binaural_channels + 1, config.binaural_channels, config.unet_channels).eval()
    out: dict = {"params": count_parameters(reference), "fused_rel_error": relative_error(reference, fused, config)}
    with tempfile.TemporaryDirectory() as tmp:
        out["checkpoint_mb"] = save_separator(Path(tmp) / f"{name}.pt", reference,
                                              classes=["speech", "music"]).stat().st_size / 1e6
    binaural = np.random.default_rng(0).standard_normal((1, 2, DEFAULT_STFT.clip_samples)).astype(np.float32)
    spec = stft(binaural)
    magnitude, phase = np.abs(spec[:, 0]), spec.mean(axis=1)
    out["numpy"] = timed_rounds({"stft": lambda: stft(binaural),
                                 "rebuild": lambda: rebuild_with_phase(magnitude, phase, length=binaural.shape[-1])},
                                repeats)
    height, width = DEFAULT_STFT.slice_shape
    bare_input = torch.rand(1, config.binaural_channels + 1, height, width)
    with torch.inference_mode():
        for batch in (1, 32):
            mixture, classes, memory = network_inputs(config, batch)
            fns = {"step": lambda: fused(mixture, classes, memory), "reference": lambda: reference(mixture, classes, memory)}
            if batch == 1:
                fns = {"clip": lambda: separate_clip(fused, binaural, 0), **fns, "bare unet": lambda: bare(bare_input)}
            n = repeats if batch == 1 else min(10, max(3, repeats // 5))
            for threads in THREADS:
                out[batch, threads] = timed_rounds(fns, n, threads=threads, warmup=5 if batch == 1 else 2)
    return out


def thread_sweep(repeats: int) -> None:
    """Fused compact step (networks only) by batch size, 1 and 2 threads timed in alternation."""
    config = SeparatorConfig.preset("compact")
    fused = fuse_for_inference(with_running_stats(Separator(config)).eval())
    print(f"\nthread sweep, fused compact step (networks), min ms of {repeats} rounds (median); "
          f"load average {load_average()}")
    print(f"{'batch':>6}" + "".join(f"{f'{t} thread(s)':>20}" for t in THREADS) + f"{'fastest':>9}{'picked':>8}")
    with torch.inference_mode():
        for batch in SWEEP_BATCHES:
            mixture, classes, memory = network_inputs(config, batch)
            fns = {threads: lambda: fused(mixture, classes, memory) for threads in THREADS}
            cells = timed_rounds(fns, repeats, threads={t: t for t in THREADS}, warmup=3)
            fastest = min(THREADS, key=lambda t: cells[t]["min"])
            print(f"{batch:>6}" + "".join(f"{cells[t]['min']:>11.2f} ({cells[t]['median']:>6.1f})" for t in THREADS)
                  + f"{fastest:>9}{min(inference_threads(batch), max(THREADS)):>8}")


def print_preset(name: str, row: dict) -> None:
    print(f"\n{name}: {row['params']:,} parameters, checkpoint {row['checkpoint_mb']:.1f} MB, "
          f"fused vs reference max error {row['fused_rel_error']:.1e} of the peak")
    print(f"{'ms':<34}" + "".join(f"{f'{t} thread(s): min':>20}{'median':>8}{'cpu':>8}" for t in THREADS))
    for batch in (1, 32):
        for candidate in row[batch, THREADS[0]]:
            cells = "".join(f"{row[batch, t][candidate]['min']:>20.2f}{row[batch, t][candidate]['median']:>8.2f}"
                            f"{row[batch, t][candidate]['cpu']:>8.2f}" for t in THREADS)
            print(f"{f'batch {batch} {candidate}':<34}{cells}")
    for part, figures in row["numpy"].items():
        print(f"{f'batch 1 {part} (numpy)':<34}{figures['min']:>20.2f}{figures['median']:>8.2f}{figures['cpu']:>8.2f}")
    best = min(THREADS, key=lambda t: row[1, t]["clip"]["min"])
    figures = {candidate: row[1, best][candidate]["min"] for candidate in row[1, best]}
    bare = figures["bare unet"]
    print(f"batch 1, best: {best} thread(s): clip (STFT + f^B + f^M + f^R + iSTFT) {figures['clip']:.2f} ms, "
          f"fused networks {figures['step']:.2f}, reference networks {figures['reference']:.2f}, bare U-Net "
          f"{bare:.2f}; ratios to the bare U-Net: clip {figures['clip'] / bare:.2f}, fused networks "
          f"{figures['step'] / bare:.2f}, reference networks {figures['reference'] / bare:.2f} "
          f"(fused / reference {figures['step'] / figures['reference']:.2f})")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=60)
    parser.add_argument("--presets", nargs="+", choices=PRESET_NAMES, default=list(PRESET_NAMES),
                        help="U-Net widths")
    parser.add_argument("--backbones", nargs="+", choices=BACKBONES, default=["unet"],
                        help="f^B / f^M networks; mmdensenet has one width of its own (the presets set U-Nets')")
    parser.add_argument("--no-sweep", action="store_true", help="skip the thread sweep over batch sizes")
    args = parser.parse_args()
    print(f"torch {torch.__version__}, {args.repeats} rounds per batch-1 figure, {os.cpu_count()} CPUs, "
          f"load average {load_average()}, OMP_WAIT_POLICY={os.environ['OMP_WAIT_POLICY']}")
    print(availability_line())
    configs = [SeparatorConfig.preset(name) for name in args.presets] if "unet" in args.backbones else []
    configs += [SeparatorConfig(backbone=name) for name in args.backbones if name != "unet"]
    for config in configs:
        print_preset(config.summary, bench_config(config, args.repeats))
    if not args.no_sweep:
        thread_sweep(args.repeats)
    print(f"\nload average at the end {load_average()}")


if __name__ == "__main__":
    main()
