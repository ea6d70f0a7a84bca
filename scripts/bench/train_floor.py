"""The arithmetic floor of a PPO env step: multiply-adds per env step of the compact recipe (policy
update, acting, separator, f^R update) and how fast this machine's cores do them, so the speed that
``scripts/bench/train.py`` measures can be set against what the work itself needs.

    python scripts/bench/train_floor.py [--reuse 0.48] [--repeats 5]

Counts come from forward hooks on every convolution and linear layer (a transposed convolution
counts its input pixels x kernel x output channels); backward is taken as twice the forward (weight
and input gradients). The throughput is one thread's forward + backward of E^B over a 320-sample
update batch, channels_last (the training path) and NCHW (the path before), CPU time, median.
"""

from __future__ import annotations

import argparse
import os
import time

os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")

import torch  # noqa: E402
from torch import nn  # noqa: E402

from m2h_ros.models.checkpoint import DEFAULT_SEPARATOR_CHECKPOINT, load_separator  # noqa: E402
from m2h_ros.models.policy import PolicyConfig, PolicyInputs, PolicyNet  # noqa: E402
from m2h_ros.training.ppo_config import PPOConfig  # noqa: E402


def multiply_adds(module: nn.Module, run) -> int:
    total = 0

    def hook(layer, inputs, output):
        nonlocal total
        if isinstance(layer, nn.ConvTranspose2d):
            total += inputs[0].numel() * layer.out_channels * layer.kernel_size[0] * layer.kernel_size[1]
        elif isinstance(layer, nn.Conv2d):
            total += output.numel() * layer.in_channels * layer.kernel_size[0] * layer.kernel_size[1]
        elif isinstance(layer, nn.Linear):
            total += output.numel() * layer.in_features

    handles = [m.register_forward_hook(hook) for m in module.modules()
               if isinstance(m, (nn.Conv2d, nn.ConvTranspose2d, nn.Linear))]
    with torch.no_grad():
        run()
    for handle in handles:
        handle.remove()
    return total


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--reuse", type=float, default=0.48, help="share of observations whose f^B/f^M are reused")
    parser.add_argument("--repeats", type=int, default=5)
    args = parser.parse_args()
    torch.set_num_threads(1)
    cfg = PPOConfig()
    net = PolicyNet(PolicyConfig.preset("compact"))
    h = net.config.hidden
    one = PolicyInputs(torch.zeros(1, 3, 64, 64, dtype=torch.uint8), torch.rand(1, 32, 32, 32), torch.rand(1, 32, 32, 32))
    policy = multiply_adds(net, lambda: net.features(one)) + 3 * (3 * h * h + h * h)  # + GRU gates
    separator = load_separator(DEFAULT_SEPARATOR_CHECKPOINT).separator
    mixture, classes = torch.rand(1, 32, 32, 32), torch.zeros(1, dtype=torch.long)
    front = multiply_adds(separator, lambda: separator.predict_monaural(
        separator.separate_binaural(mixture, classes)[1], classes))
    refiner = multiply_adds(separator.refiner, lambda: separator.refiner(torch.rand(1, 16, 32, 32),
                                                                         torch.rand(1, 16, 32, 32)))
    parts = {"PPO update": cfg.ppo_epochs * 3 * policy, "acting": policy,
             "separator": (1 - args.reuse) * front + refiner, "f^R update (when trained)": cfg.refiner_epochs * 3 * refiner}
    print("multiply-adds per env step: " + ", ".join(f"{k} {v / 1e6:.1f} M" for k, v in parts.items()))
    batch = cfg.n_envs * cfg.n_steps
    x = torch.rand(batch, 32, 32, 32)
    for name, data in (("channels_last", x.contiguous(memory_format=torch.channels_last)), ("NCHW", x)):
        encoder = net.audio_encoder.cnn  # the module itself: no layout conversion in between
        times = []
        for _ in range(args.repeats + 1):
            start = time.process_time()
            encoder(data).sum().backward()
            times.append(time.process_time() - start)
        seconds = sorted(times[1:])[len(times[1:]) // 2]
        work = 3 * batch * multiply_adds(net.audio_encoder, lambda: net.audio_encoder(x[:1]))
        print(f"E^B forward + backward over {batch} samples, 1 thread, {name}: {1e3 * seconds:.0f} CPU ms, "
              f"{work / seconds / 1e9:.0f} G multiply-adds/s")
    print(f"load average {os.getloadavg()[0]:.1f}")


if __name__ == "__main__":
    main()
