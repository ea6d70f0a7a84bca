"""DD-PPO's collective operations (``torch.distributed``, launched by ``torchrun``); with one worker they
do nothing, so the training loop reads the same either way."""

from __future__ import annotations

import os

import numpy as np
import torch
import torch.distributed as dist


def init_distributed(device: torch.device) -> tuple[int, int]:
    """(rank, world size): joins the torchrun group when launched by torchrun, else (0, 1). ``device``: where
    this worker trains (``models.device.resolve_device``)."""
    if int(os.environ.get("WORLD_SIZE", "1")) > 1 and not dist.is_initialized():
        if device.type == "cuda":
            torch.cuda.set_device(device)
        # nccl takes CUDA tensors, one GPU per worker; gloo the CPU's, and CUDA tensors of workers sharing a GPU.
        one_gpu_each = device.type == "cuda" and int(os.environ.get("LOCAL_WORLD_SIZE", "1")) <= torch.cuda.device_count()
        dist.init_process_group("nccl" if one_gpu_each else "gloo")
    if dist.is_initialized():
        return dist.get_rank(), dist.get_world_size()
    return 0, 1


def close_distributed() -> None:
    """Leave the torchrun group :func:`init_distributed` joined, if any (the end of a run)."""
    if dist.is_initialized():
        dist.destroy_process_group()


def all_reduce_mean(tensors: list[torch.Tensor], world: int) -> None:
    """Average tensors in place over all workers (one flat all-reduce)."""
    if world == 1 or not tensors:
        return
    flat = torch.cat([t.reshape(-1) for t in tensors])
    dist.all_reduce(flat)
    flat /= world
    offset = 0
    for t in tensors:
        t.copy_(flat[offset: offset + t.numel()].view_as(t))
        offset += t.numel()


def all_reduce_sum(values: np.ndarray, world: int, device: torch.device) -> np.ndarray:
    if world == 1:
        return values
    tensor = torch.as_tensor(values, dtype=torch.float64, device=device)
    dist.all_reduce(tensor)
    return tensor.cpu().numpy()
