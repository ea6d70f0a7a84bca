#!/usr/bin/env python3
"""What the separator node computes per 1 s frame on one core, with each audio output: f^B -> f^M -> f^R
plus the listener output (the default), against the same step with f^B's masked mixture (the earlier
default) as the reference, measured in the same run, interleaved, on one torch thread. Prints the median,
p90 and the spread over rounds (median of each round of ``--repeats`` frames), and the machine's load.

    python scripts/bench/listener.py [--repeats 100] [--rounds 5]
"""

from __future__ import annotations

import argparse
import os
import sys
import time

os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")

import numpy as np  # noqa: E402
import torch  # noqa: E402

from m2h_ros.models.checkpoint import DEFAULT_SEPARATOR_CHECKPOINT, load_separator  # noqa: E402
from m2h_ros.models.listener import DEFAULT_LISTENER_CHECKPOINT, load_listener  # noqa: E402
from m2h_ros.models.runner import SeparatorRunner  # noqa: E402
from m2h_ros.paths import file_label  # noqa: E402


def frame_of_noise(seed: int) -> np.ndarray:
    rng = np.random.default_rng(seed)
    left = 0.5 * rng.standard_normal(16000)
    return np.stack([left, 0.8 * np.roll(left, 8) + 0.3 * rng.standard_normal(16000)])[None].astype(np.float32)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=100, help="frames per output per round")
    parser.add_argument("--rounds", type=int, default=5)
    args = parser.parse_args(argv)
    torch.set_num_threads(1)
    loaded = load_separator(DEFAULT_SEPARATOR_CHECKPOINT)
    runner = SeparatorRunner(loaded, 1, listener=load_listener(DEFAULT_LISTENER_CHECKPOINT))
    classes = runner.class_indices(["speech"])
    frames = [frame_of_noise(seed) for seed in range(8)]

    def listener_output(k: int) -> None:
        runner.step(frames[k % 8], classes, np.array([k == 0]))
        runner.listen(frames[k % 8], classes)

    def masked_output(k: int) -> None:
        runner.step(frames[k % 8], classes, np.array([k == 0])).waveform(
            frames[k % 8], config=loaded.stft, output="masked_mixture", binaural=True)

    outputs = {"listener (default)": listener_output, "masked_mixture (reference)": masked_output}
    for run in outputs.values():  # warm-up: oneDNN packs its weights on first use
        for k in range(5):
            run(k)
    times = {name: [] for name in outputs}
    load_before = os.getloadavg()[0]
    for _ in range(args.rounds):
        for k in range(args.repeats):
            for name, run in outputs.items():  # interleaved: both see the same machine
                started = time.perf_counter()
                run(k)
                times[name].append(1000 * (time.perf_counter() - started))
    print(f"models: {file_label(DEFAULT_SEPARATOR_CHECKPOINT)}, {file_label(DEFAULT_LISTENER_CHECKPOINT)}")
    print(f"one torch thread, {args.rounds} rounds x {args.repeats} frames of 1 s; "
          f"load {load_before:.1f} before, {os.getloadavg()[0]:.1f} after ({os.cpu_count()} CPUs)")
    medians = {}
    for name, values in times.items():
        values = np.array(values)
        rounds = np.median(values.reshape(args.rounds, args.repeats), axis=1)
        medians[name] = np.median(values)
        print(f"  {name}: median {medians[name]:.2f} ms, p90 {np.percentile(values, 90):.2f} ms per frame "
              f"(round medians {rounds.min():.2f} to {rounds.max():.2f})")
    listener, reference = medians.values()
    print(f"  ratio listener / reference: {listener / reference:.2f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
