#!/usr/bin/env python3
"""Network cost on CUDA against the CPU of the same machine, in one run: separator inference, the
separator node's whole step, a separator training step, and a PPO minibatch update of the policy, for
the compact and paper presets.

* ``separator step``: the fused f^B + f^M + f^R (``fuse_for_inference``) under ``torch.inference_mode``,
  at batch 1, 16 and 256 (the networks only; STFT and inverse STFT run in numpy on the CPU either way).
  On CUDA also under bf16 autocast.
* ``node step``: what ``separator_node`` does per message on either ``device``: ``SeparatorRunner``
  over 1 slot (the node) and 32 (in-process evaluation) with the shipped checkpoint, its three outputs
  read back as arrays and the refined estimate rebuilt into a waveform (the numpy STFTs run on the CPU
  either way; one torch thread, as the node runs).
* ``separator train``: forward, L1 on all three outputs, backward and one Adam step at batch 32 (the
  training modules, BatchNorm in train mode).
* ``policy update``: one PPO minibatch as ``training/ppo.py`` runs it: ``PolicyNet.evaluate`` over a
  20-step rollout of 16 slots (PPOConfig's defaults; the shipped pi^Q's recipe updates 32 slots at once)
  with the camera, backward and an Adam step.

Each candidate's CPU and CUDA figures are timed in alternating rounds (the CPU with all its cores as
torch threads unless ``--cpu-threads``), after warm-up; CUDA timings synchronise the device. CUDA runs
with the project's settings (``models.device.resolve_device``: deterministic kernels, float32 without
TF32; figures taken with cuDNN's autotuning and TF32 convolutions differ). Printed: the
median and the minimum ms of ``--repeats`` rounds and the CPU / CUDA ratio of the medians, with the load
average before and after. Without CUDA it prints the CPU figures alone and says so.

    python scripts/bench/gpu.py [--repeats 20] [--presets compact paper] [--cpu-threads N]
"""

from __future__ import annotations

import argparse
import os
import time
from collections.abc import Callable

os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")  # see scripts/bench/separator.py

import numpy as np  # noqa: E402
import torch  # noqa: E402

from m2h_ros.models.checkpoint import DEFAULT_SEPARATOR_CHECKPOINT, load_separator  # noqa: E402
from m2h_ros.models.device import resolve_device  # noqa: E402
from m2h_ros.models.inference import fuse_for_inference  # noqa: E402
from m2h_ros.models.runner import SeparatorRunner  # noqa: E402
from m2h_ros.models.threads import torch_threads  # noqa: E402
from m2h_ros.models.policy import PolicyConfig, PolicyNet, policy_input_buffers  # noqa: E402
from m2h_ros.models.separator import PRESET_NAMES, Separator, SeparatorConfig, count_parameters  # noqa: E402
from m2h_ros.core.audio.stft import DEFAULT_STFT  # noqa: E402
from m2h_ros.machine import availability_line, load_average  # noqa: E402

INFERENCE_BATCHES = (1, 16, 256)
NODE_SLOTS = (1, 32)
TRAIN_BATCH = 32
ROLLOUT_STEPS, ROLLOUT_SLOTS = 20, 16


def synchronise(device: torch.device) -> None:
    if device.type == "cuda":
        torch.cuda.synchronize(device)


def timed(fns: dict[str, tuple[Callable[[], object], torch.device]], repeats: int, *, warmup: int = 3) -> dict:
    """Median and min wall ms per candidate over ``repeats`` rounds, each round running every candidate once."""
    for fn, device in fns.values():
        for _ in range(warmup):
            fn()
        synchronise(device)
    wall: dict[str, list[float]] = {name: [] for name in fns}
    for _ in range(repeats):
        for name, (fn, device) in fns.items():
            synchronise(device)
            start = time.perf_counter()
            fn()
            synchronise(device)
            wall[name].append(1000.0 * (time.perf_counter() - start))
    return {name: {"median": float(np.median(ms)), "min": min(ms)} for name, ms in wall.items()}


def separator_inputs(config: SeparatorConfig, batch: int, device: torch.device):
    height, width = DEFAULT_STFT.slice_shape
    generator = torch.Generator().manual_seed(batch)
    mixture = torch.rand((batch, config.binaural_channels, height, width), generator=generator) * 10
    memory = torch.rand((batch, config.monaural_channels, height, width), generator=generator)
    channels_last = dict(memory_format=torch.channels_last)
    return (mixture.to(device).contiguous(**channels_last), torch.zeros(batch, dtype=torch.long, device=device),
            memory.to(device).contiguous(**channels_last))


def inference_candidates(config: SeparatorConfig, batch: int, devices: list[torch.device]) -> dict:
    fns = {}
    for device in devices:
        torch.manual_seed(0)
        fused = fuse_for_inference(Separator(config).eval()).to(device)
        inputs = separator_inputs(config, batch, device)

        def run(fused=fused, inputs=inputs) -> None:
            with torch.inference_mode():
                fused(*inputs)
        fns[device.type] = (run, device)
        if device.type == "cuda":
            def run_bf16(fused=fused, inputs=inputs) -> None:
                with torch.inference_mode(), torch.autocast("cuda", dtype=torch.bfloat16):
                    fused(*inputs)
            fns["cuda bf16"] = (run_bf16, device)
    return fns


def node_step_candidates(slots: int, devices: list[torch.device]) -> dict:
    fns = {}
    for device in devices:
        loaded = load_separator(DEFAULT_SEPARATOR_CHECKPOINT, map_location=device)
        runner = SeparatorRunner(loaded, slots)
        config = loaded.stft
        mixture = (np.random.default_rng(slots).standard_normal((slots, 2, config.clip_samples)) * 0.1).astype(np.float32)
        classes = np.zeros(slots, np.int64)
        runner.step(mixture, classes, np.ones(slots, bool))  # every slot's first step: memory made
        held = np.zeros(slots, bool)

        def run(runner=runner, mixture=mixture, classes=classes, held=held, config=config) -> None:
            out = runner.step(mixture, classes, held)
            out.binaural, out.monaural  # noqa: B018 (read back as the node publishes them)
            out.waveform(mixture, config=config)
        fns[device.type] = (run, device)
    return fns


def separator_train_candidates(config: SeparatorConfig, devices: list[torch.device]) -> dict:
    fns = {}
    for device in devices:
        torch.manual_seed(0)
        separator = Separator(config).to(device).train()
        optimizer = torch.optim.Adam(separator.parameters(), lr=1e-4)
        inputs = separator_inputs(config, TRAIN_BATCH, device)

        def run(separator=separator, optimizer=optimizer, inputs=inputs) -> None:
            out = separator(*inputs)
            loss = sum(x.abs().mean() for x in (out.binaural, out.monaural, out.refined))
            optimizer.zero_grad()
            loss.backward()
            optimizer.step()
        fns[device.type] = (run, device)
    return fns


def policy_candidates(config: PolicyConfig, devices: list[torch.device]) -> dict:
    fns = {}
    for device in devices:
        torch.manual_seed(0)
        net = PolicyNet(config).to(device)
        optimizer = torch.optim.Adam(net.parameters(), lr=1e-4)
        buffers = policy_input_buffers(config, steps=ROLLOUT_STEPS, slots=ROLLOUT_SLOTS)
        for tensor in buffers:
            if tensor is not None:
                tensor.copy_(torch.randint(0, 255, tensor.shape) if tensor.dtype == torch.uint8 else torch.rand(tensor.shape))
        inputs = buffers.flat().to(device)
        hidden = net.initial_hidden(ROLLOUT_SLOTS).to(device)
        starts = torch.zeros((ROLLOUT_STEPS, ROLLOUT_SLOTS), dtype=torch.bool, device=device)
        starts[0] = True
        actions = torch.randint(0, config.n_actions, (ROLLOUT_STEPS, ROLLOUT_SLOTS, 1), device=device)

        def run(net=net, optimizer=optimizer, inputs=inputs, hidden=hidden, starts=starts, actions=actions) -> None:
            out = net.evaluate(inputs, hidden, starts)
            log_probs = torch.log_softmax(out.logits, dim=-1)
            loss = -log_probs.gather(2, actions).mean() + 0.5 * out.value.square().mean()
            optimizer.zero_grad()
            loss.backward()
            optimizer.step()
        fns[device.type] = (run, device)
    return fns


def print_rows(title: str, figures: dict) -> None:
    reference = figures.get("cpu", {}).get("median")
    cells = []
    for name, cell in figures.items():
        ratio = f", CPU / this {reference / cell['median']:.1f}x" if name != "cpu" and reference else ""
        cells.append(f"{name} {cell['median']:.2f} (min {cell['min']:.2f}){ratio}")
    print(f"{title:<42}" + "; ".join(cells))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=20)
    parser.add_argument("--presets", nargs="+", choices=PRESET_NAMES, default=list(PRESET_NAMES))
    parser.add_argument("--cpu-threads", type=int, default=os.cpu_count(), help="torch threads on the CPU")
    args = parser.parse_args()
    if args.repeats < 1 or args.cpu_threads < 1:
        parser.error("--repeats and --cpu-threads must be positive")
    torch.set_num_threads(args.cpu_threads)
    devices = [torch.device("cpu")]
    if torch.cuda.is_available():
        # As the trainers and the separator node run on CUDA: deterministic kernels, IEEE float32 (no TF32).
        devices.append(resolve_device("cuda", field="--device"))
        gpu = torch.cuda.get_device_name()
    else:
        gpu = "none (CPU figures only)"
    print(f"torch {torch.__version__}; GPU: {gpu}; {os.cpu_count()} CPUs, {args.cpu_threads} torch threads on the "
          f"CPU; {args.repeats} rounds; load average {load_average()}")
    print(availability_line())
    print("ms per call, median (min); ratio = CPU median / CUDA median")
    for preset in args.presets:
        separator = SeparatorConfig.preset(preset)
        policy = PolicyConfig.preset(preset, stop=True)
        print(f"\n{preset}: separator {count_parameters(Separator(separator)):,} parameters, "
              f"policy {count_parameters(PolicyNet(policy)):,}")
        for batch in INFERENCE_BATCHES:
            # A paper-width batch of 256 takes seconds per call on 2 cores: fewer rounds there.
            repeats = args.repeats if batch < 256 else max(2, args.repeats // 5)
            print_rows(f"separator step, batch {batch}", timed(inference_candidates(separator, batch, devices), repeats))
        if preset == "compact":  # the shipped checkpoint's preset
            with torch_threads(1):  # the separator node's thread count
                for slots in NODE_SLOTS:
                    print_rows(f"node step (shipped), {slots} slot(s)",
                               timed(node_step_candidates(slots, devices), args.repeats))
        print_rows(f"separator train step, batch {TRAIN_BATCH}",
                   timed(separator_train_candidates(separator, devices), max(2, args.repeats // 2)))
        print_rows(f"policy update, {ROLLOUT_STEPS} x {ROLLOUT_SLOTS} steps",
                   timed(policy_candidates(policy, devices), max(2, args.repeats // 2)))
    print(f"\nload average after: {load_average()}")


if __name__ == "__main__":
    main()
