"""Where a run puts its networks: one rule for every trainer, the separator node and ``m2h-separate``.

On CUDA they ask for deterministic kernels (cuDNN's deterministic algorithms, PyTorch's
deterministic mode, cuBLAS's fixed workspace): without them two runs of one seed, or a resumed run and
an uninterrupted one, part after a few updates (measured on an H200, docs/design/measurements.md), and a
resumed run must equal an uninterrupted one on any device. And float32 stays float32: cuDNN's default
TF32 convolutions put the shipped separator's output 5.6e-4 of its peak from the CPU's (an H200), where IEEE float32 on either device agree to float tolerance."""

from __future__ import annotations

import os

import torch

from m2h_ros.config import DEVICES
from m2h_ros.errors import ConfigError

__all__ = ["DEVICES", "check_device", "deterministic_cuda", "ieee_float32_cuda", "resolve_device"]


def check_device(name: str, *, field: str) -> None:
    if name not in DEVICES:
        raise ConfigError(f"{field}={name!r} must be auto, cpu or cuda")


def resolve_device(name: str, *, field: str) -> torch.device:
    """The device ``name`` means on this machine; under torchrun, CUDA device LOCAL_RANK (one GPU per worker;
    with more workers than GPUs, they share them in turn). ``cuda`` without a CUDA device is a ConfigError
    naming ``field``."""
    check_device(name, field=field)
    if name == "cuda" and not torch.cuda.is_available():
        raise ConfigError(f"{field}='cuda' but no CUDA device is available")
    if name != "cpu" and torch.cuda.is_available():
        deterministic_cuda()
        ieee_float32_cuda()
        return torch.device("cuda", int(os.environ.get("LOCAL_RANK", "0")) % torch.cuda.device_count())
    return torch.device("cpu")


def deterministic_cuda() -> None:
    """Deterministic CUDA kernels for this process (the workspace setting counts only before cuBLAS first
    runs, so a trainer asks for it before it builds its networks); an operation without a deterministic
    kernel warns instead of failing."""
    os.environ.setdefault("CUBLAS_WORKSPACE_CONFIG", ":4096:8")
    torch.backends.cudnn.deterministic = True
    torch.backends.cudnn.benchmark = False
    torch.use_deterministic_algorithms(True, warn_only=True)


def ieee_float32_cuda() -> None:
    """float32 matrix products, convolutions and recurrent layers on CUDA compute in float32, as on the CPU,
    not in TF32 (a 10-bit mantissa; cuDNN's default for convolutions). Through the flags torch has long had:
    torch 2.13 refuses to read them once its newer ``fp32_precision`` settings were used."""
    torch.backends.cuda.matmul.allow_tf32 = False
    torch.backends.cudnn.allow_tf32 = False
