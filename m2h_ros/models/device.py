"""Where a run puts its networks: one rule for every trainer, the separator node and ``m2h-separate``.

On CUDA they ask for deterministic kernels (cuDNN's deterministic algorithms, PyTorch's
deterministic mode, cuBLAS's fixed workspace): without them two runs of one seed, or a resumed run and
an uninterrupted one, part after a few updates (measured on an H200, docs/measurements.md), and a
resumed run must equal an uninterrupted one on any device."""

from __future__ import annotations

import os

import torch

from m2h_ros.config import DEVICES
from m2h_ros.errors import ConfigError

__all__ = ["DEVICES", "check_device", "deterministic_cuda", "resolve_device"]


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
