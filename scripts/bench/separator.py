#!/usr/bin/env python3
"""Separator cost on CPU: ms per step of f^B + f^M + f^R, reference and fused, by thread count.

Per preset, at batch 1 with 1 and 2 torch threads:

* ``clip``: the whole per-step path a node runs, ``separate_clip`` on a 1 s binaural waveform with the
  fused model (``fuse_for_inference``): STFT, f^B, f^M, f^R, and the mixture-phase inverse STFT.
  Its parts: ``stft`` and ``rebuild`` (numpy, one thread), ``step`` (the networks only).
* ``reference``: the networks as trained (eager, BatchNorm layers), under ``torch.inference_mode``.
* ``bare unet``: one plain eager U-Net of the same widths (33 -> 32 channels, BatchNorm, eval). A step
  runs two U-Nets plus the refiner, so ``clip / bare unet`` near 2 means no cost beyond two plain
  U-Net forwards; below 2, the fused path beats the plain layers.

Then batch 32, and (compact) a thread sweep over batch sizes, next to what
``models.threads.inference_threads`` picks. The fused outputs are checked against the reference
(max error relative to the peak). Every figure is the median and the minimum of ``--repeats`` runs
(batch 32: a fifth of them, 3 to 10);
on a shared machine the minimum is the better estimate of the uncontended cost, and the CPU time of
one thread (``cpu``) is the figure least disturbed by other processes. The load average is printed
before and after.

    .venv/bin/python scripts/bench/separator.py [--repeats 60] [--presets compact paper] [--no-sweep]
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
    PRESET_NAMES,
    Separator,
    SeparatorConfig,
    count_parameters,
    separate_clip,
)
from m2h_ros.models.threads import inference_threads  # noqa: E402
from m2h_ros.models.unet import UNet  # noqa: E402

THREADS = (1, 2)
SWEEP_BATCHES = (1, 2, 4, 8, 16, 32)


def timed_ms(fn: Callable[[], object], repeats: int, *, clock=time.perf_counter, warmup: int = 5) -> tuple[float, float]:
    """(median, minimum) time in ms by ``clock``."""
    for _ in range(warmup):
        fn()
    times = []
    for _ in range(repeats):
        start = clock()
        fn()
        times.append(clock() - start)
    return 1000.0 * float(np.median(times)), 1000.0 * min(times)


def load_average() -> str:
    return ", ".join(f"{x:.2f}" for x in os.getloadavg())


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


def bench_preset(name: str, repeats: int) -> dict[str, float]:
    torch.manual_seed(0)
    config = SeparatorConfig.preset(name)
    reference = with_running_stats(Separator(config)).eval()
    fused = fuse_for_inference(reference)
    bare = UNet(config.binaural_channels + 1, config.binaural_channels, config.unet_channels).eval()
    row: dict[str, float] = {"params": count_parameters(reference), "fused_rel_error": relative_error(reference, fused, config)}
    with tempfile.TemporaryDirectory() as tmp:
        path = save_separator(Path(tmp) / f"{name}.pt", reference, classes=["speech", "music"])
        row["checkpoint_mb"] = path.stat().st_size / 1e6
    binaural = np.random.default_rng(0).standard_normal((1, 2, DEFAULT_STFT.clip_samples)).astype(np.float32)
    spec = stft(binaural)
    magnitude, phase = np.abs(spec[:, 0]), spec.mean(axis=1)
    row["stft_ms"], row["stft_ms_min"] = timed_ms(lambda: stft(binaural), repeats)
    row["rebuild_ms"], row["rebuild_ms_min"] = timed_ms(
        lambda: rebuild_with_phase(magnitude, phase, length=binaural.shape[-1]), repeats)
    height, width = DEFAULT_STFT.slice_shape
    bare_input = torch.rand(1, config.binaural_channels + 1, height, width)
    for batch in (1, 32):
        n = repeats if batch == 1 else min(10, max(3, repeats // 5))
        warmup = 5 if batch == 1 else 2
        mixture, classes, memory = network_inputs(config, batch)
        for threads in THREADS:
            torch.set_num_threads(threads)
            tag = f"b{batch}_t{threads}"
            with torch.inference_mode():
                for label, model in (("reference", reference), ("step", fused)):
                    row[f"{label}_{tag}"], row[f"{label}_{tag}_min"] = timed_ms(
                        lambda m=model: m(mixture, classes, memory), n, warmup=warmup)
                if batch == 1:
                    row[f"bare_{tag}"], row[f"bare_{tag}_min"] = timed_ms(lambda: bare(bare_input), n)
            if batch == 1:
                row[f"clip_{tag}"], row[f"clip_{tag}_min"] = timed_ms(lambda: separate_clip(fused, binaural, 0), n)
        if batch == 1:  # CPU time of one thread: barely affected by other processes on the machine
            torch.set_num_threads(1)
            row["clip_b1_cpu"], _ = timed_ms(lambda: separate_clip(fused, binaural, 0), n, clock=time.process_time)
            row["reference_b1_cpu"], _ = timed_ms(lambda: reference(mixture, classes, memory), n,
                                                  clock=time.process_time)
    return row


def thread_sweep(repeats: int) -> None:
    """Fused compact step (networks only), min ms by batch size and thread count."""
    config = SeparatorConfig.preset("compact")
    fused = fuse_for_inference(with_running_stats(Separator(config)).eval())
    print("\nthread sweep, fused compact step (networks), min ms of "
          f"{repeats} runs (median in brackets); load average {load_average()}")
    print(f"{'batch':>6}" + "".join(f"{f'{t} thread(s)':>22}" for t in THREADS) + f"{'fastest':>9}{'picked':>8}")
    with torch.inference_mode():
        for batch in SWEEP_BATCHES:
            mixture, classes, memory = network_inputs(config, batch)
            cells = {}
            for threads in THREADS:
                torch.set_num_threads(threads)
                cells[threads] = timed_ms(lambda: fused(mixture, classes, memory), repeats, warmup=3)
            fastest = min(THREADS, key=lambda t: cells[t][1])
            print(f"{batch:>6}" + "".join(f"{cells[t][1]:>12.2f} ({cells[t][0]:>7.2f})" for t in THREADS)
                  + f"{fastest:>9}{min(inference_threads(batch), max(THREADS)):>8}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=60)
    parser.add_argument("--presets", nargs="+", choices=PRESET_NAMES, default=list(PRESET_NAMES))
    parser.add_argument("--no-sweep", action="store_true", help="skip the thread sweep over batch sizes")
    args = parser.parse_args()
    print(f"torch {torch.__version__}, {args.repeats} runs per figure (median, and min), {os.cpu_count()} CPUs, "
          f"load average {load_average()}, OMP_WAIT_POLICY={os.environ['OMP_WAIT_POLICY']}")
    rows = {name: bench_preset(name, args.repeats) for name in args.presets}
    columns = ["params", "checkpoint_mb", "fused_rel_error", "stft_ms", "stft_ms_min", "rebuild_ms", "rebuild_ms_min"]
    for batch in (1, 32):
        for threads in THREADS:
            labels = ("clip", "step", "reference", "bare") if batch == 1 else ("step", "reference")
            columns += [f"{label}_b{batch}_t{threads}{suffix}" for label in labels for suffix in ("", "_min")]
    columns += ["clip_b1_cpu", "reference_b1_cpu"]
    print(f"{'figure (ms unless named)':<28}" + "".join(f"{name:>14}" for name in rows))
    for column in columns:
        cells = "".join(f"{row[column]:>14,.0f}" if column == "params" else f"{row[column]:>14.4g}"
                        for row in rows.values())
        print(f"{column:<28}{cells}")
    print("\nbatch 1, best thread count by min:")
    for name, row in rows.items():
        best = min(THREADS, key=lambda t: row[f"clip_b1_t{t}_min"])
        clip, bare = row[f"clip_b1_t{best}_min"], row[f"bare_b1_t{best}_min"]
        reference = row[f"reference_b1_t{best}_min"]
        print(f"  {name}: {best} thread(s): clip (STFT + f^B + f^M + f^R + iSTFT) {clip:.2f} ms "
              f"(median {row[f'clip_b1_t{best}']:.2f}), networks {row[f'step_b1_t{best}_min']:.2f} ms, "
              f"reference networks {reference:.2f} ms, bare U-Net {bare:.2f} ms; "
              f"clip / bare U-Net {clip / bare:.2f}, fused networks / bare U-Net "
              f"{row[f'step_b1_t{best}_min'] / bare:.2f}, reference networks / bare U-Net {reference / bare:.2f}")
    if "paper" in rows:
        for name, row in rows.items():
            if name != "paper":
                print(f"{name} / paper: params {row['params'] / rows['paper']['params']:.3f}, clip b1 t1 "
                      f"{row['clip_b1_t1_min'] / rows['paper']['clip_b1_t1_min']:.3f}, step b32 t2 "
                      f"{row['step_b32_t2_min'] / rows['paper']['step_b32_t2_min']:.3f}")
    if not args.no_sweep:
        thread_sweep(args.repeats)
    print(f"\nload average at the end {load_average()}")


if __name__ == "__main__":
    main()
