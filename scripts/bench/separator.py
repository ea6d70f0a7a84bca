#!/usr/bin/env python3
"""Separator cost on CPU: ms per step of f^B + f^M + f^R (2 torch threads), real-time factor, sizes.

One step separates one 1 s clip, so the real-time factor is median step time / 1 s (per clip at
batch 32). Medians and minima are printed with the load average: on a shared machine the minimum is
the better estimate of the uncontended cost, and the single-thread CPU time per step (median) is the
figure least disturbed by other processes.
Also times the full waveform path (STFT -> step -> mixture-phase iSTFT) at batch 1, and reports each
preset's figures relative to the paper preset measured in the same run.

    .venv/bin/python scripts/bench/separator.py [--repeats 30] [--presets compact paper]
"""

from __future__ import annotations

import argparse
import os
import tempfile
import time
from pathlib import Path

# Idle OpenMP threads sleep instead of spinning (libgomp reads this when torch loads): spinning threads
# are many times slower whenever the 2 cores are shared. Override by setting the variable yourself.
os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")

import numpy as np  # noqa: E402
import torch  # noqa: E402

from m2h_ros.core.audio.stft import DEFAULT_STFT  # noqa: E402
from m2h_ros.models.checkpoint import save_separator  # noqa: E402
from m2h_ros.models.separator import (  # noqa: E402
    PRESET_NAMES,
    Separator,
    SeparatorConfig,
    count_parameters,
    separate_clip,
)


def timed_ms(fn, repeats: int, *, clock=time.perf_counter, warmup: int = 5) -> tuple[float, float]:
    """(median, minimum) time in ms by ``clock``; on a shared machine the minimum is the uncontended cost."""
    for _ in range(warmup):
        fn()
    times = []
    for _ in range(repeats):
        start = clock()
        fn()
        times.append(clock() - start)
    return 1000.0 * float(np.median(times)), 1000.0 * min(times)


def bench_preset(name: str, repeats: int) -> dict[str, float]:
    torch.manual_seed(0)
    separator = Separator(SeparatorConfig.preset(name)).eval()
    height, width = DEFAULT_STFT.slice_shape
    bins, monos = separator.config.binaural_channels, separator.config.monaural_channels
    row: dict[str, float] = {"params": count_parameters(separator)}
    for part in ("binaural_separator", "monaural_predictor", "refiner"):
        row[f"params_{part}"] = count_parameters(getattr(separator, part))
    with tempfile.TemporaryDirectory() as tmp:
        path = save_separator(Path(tmp) / f"{name}.pt", separator, classes=["speech", "music"])
        row["checkpoint_mb"] = path.stat().st_size / 1e6
    with torch.inference_mode():
        for batch in (1, 32):
            mixture = torch.rand(batch, bins, height, width) * 10
            classes = torch.zeros(batch, dtype=torch.long)
            memory = torch.rand(batch, monos, height, width)
            step = lambda x=mixture, c=classes, m=memory: separator(x, c, m)  # noqa: E731
            row[f"step_ms_b{batch}"], row[f"step_ms_b{batch}_min"] = timed_ms(step, repeats)
            if batch == 1:  # CPU time of one thread: barely affected by other processes on the machine
                torch.set_num_threads(1)
                row["step_cpu_ms_b1_1thread"], _ = timed_ms(step, repeats, clock=time.process_time)
                torch.set_num_threads(2)
    binaural = np.random.default_rng(0).standard_normal((1, 2, DEFAULT_STFT.clip_samples)).astype(np.float32)
    row["waveform_ms_b1"], row["waveform_ms_b1_min"] = timed_ms(lambda: separate_clip(separator, binaural, 0), repeats)
    clip_ms = 1000.0 * DEFAULT_STFT.clip_samples / DEFAULT_STFT.sample_rate
    row["rtf_b1"] = row["step_ms_b1"] / clip_ms
    row["rtf_b32_per_clip"] = row["step_ms_b32"] / 32 / clip_ms
    return row


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=30)
    parser.add_argument("--presets", nargs="+", choices=PRESET_NAMES, default=list(PRESET_NAMES))
    args = parser.parse_args()
    torch.set_num_threads(2)
    load = ", ".join(f"{x:.2f}" for x in os.getloadavg())
    print(f"torch {torch.__version__}, {torch.get_num_threads()} threads, {args.repeats} runs per figure "
          f"(median, and min), {os.cpu_count()} CPUs, load average {load}, "
          f"OMP_WAIT_POLICY={os.environ['OMP_WAIT_POLICY']}")
    rows = {name: bench_preset(name, args.repeats) for name in args.presets}
    columns = ["params", "params_binaural_separator", "params_monaural_predictor", "params_refiner", "checkpoint_mb",
               "step_ms_b1", "step_ms_b1_min", "step_cpu_ms_b1_1thread", "step_ms_b32", "step_ms_b32_min",
               "waveform_ms_b1", "waveform_ms_b1_min", "rtf_b1", "rtf_b32_per_clip"]
    print(f"{'figure':<28}" + "".join(f"{name:>14}" for name in rows))
    for column in columns:
        cells = "".join(f"{row[column]:>14,.0f}" if column.startswith("params") else f"{row[column]:>14.4g}"
                        for row in rows.values())
        print(f"{column:<28}{cells}")
    if "paper" in rows:
        for name, row in rows.items():
            if name != "paper":
                print(f"{name} / paper: params {row['params'] / rows['paper']['params']:.3f}, "
                      f"step b1 {row['step_ms_b1'] / rows['paper']['step_ms_b1']:.3f}, "
                      f"step b32 {row['step_ms_b32'] / rows['paper']['step_ms_b32']:.3f}")


if __name__ == "__main__":
    main()
