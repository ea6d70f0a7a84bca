"""Where a training run puts its networks: one rule for every trainer."""

from __future__ import annotations

import os

import torch

from m2h_ros.errors import ConfigError

DEVICES = ("auto", "cpu", "cuda")  # auto: CUDA when present, else the CPU


def check_device(name: str, *, field: str) -> None:
    if name not in DEVICES:
        raise ConfigError(f"{field}={name!r} must be auto, cpu or cuda")


def training_device(name: str, *, field: str) -> torch.device:
    """The device ``name`` means on this machine; under torchrun, CUDA device LOCAL_RANK (one GPU per worker)."""
    check_device(name, field=field)
    if name == "cuda" and not torch.cuda.is_available():
        raise ConfigError(f"{field}='cuda' but no CUDA device is available")
    if name != "cpu" and torch.cuda.is_available():
        return torch.device("cuda", int(os.environ.get("LOCAL_RANK", "0")))
    return torch.device("cpu")
