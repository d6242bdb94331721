"""Data-parallel training under ``torchrun``: one trainer per process, gradients averaged.

Each process owns its envs (its share of the training scenes) and seeds them with
``seed + 1000·rank``; all processes start from rank 0's parameters and average their
gradients before every optimizer step, so parameters stay identical everywhere. Rank 0
alone writes logs and checkpoints. The backend is NCCL on CUDA devices and gloo on CPU.

Outside ``torchrun`` (no ``WORLD_SIZE`` in the environment) everything is a no-op.
"""

from __future__ import annotations

import os
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from typing import TypeVar

import torch
import torch.distributed as dist
from torch import nn

T = TypeVar("T")

#: Seed stride between processes.
RANK_SEED_STRIDE = 1000


@dataclass(frozen=True)
class DistInfo:
    """Where this process sits in the job.

    Attributes:
        rank: Global rank.
        world_size: Number of processes.
        local_rank: Rank on this machine (picks the CUDA device).
    """

    rank: int = 0
    world_size: int = 1
    local_rank: int = 0

    @property
    def is_main(self) -> bool:
        """Rank 0: writes logs and checkpoints."""
        return self.rank == 0

    @property
    def enabled(self) -> bool:
        """More than one process."""
        return self.world_size > 1

    def seed(self, base: int) -> int:
        """Rank-aware seed."""
        return base + RANK_SEED_STRIDE * self.rank


def setup(device: str) -> tuple[DistInfo, torch.device]:
    """Join the process group if launched by ``torchrun``; returns the info and device.

    Args:
        device: ``cpu`` or ``cuda`` (``cuda`` becomes ``cuda:LOCAL_RANK``).
    """
    world = int(os.environ.get("WORLD_SIZE", "1"))
    if world <= 1:
        return DistInfo(), torch.device(device)
    info = DistInfo(int(os.environ["RANK"]), world, int(os.environ.get("LOCAL_RANK", "0")))
    dev = torch.device(device)
    if dev.type == "cuda":
        dev = torch.device("cuda", info.local_rank)
        torch.cuda.set_device(dev)
    if not dist.is_initialized():
        dist.init_process_group("nccl" if dev.type == "cuda" else "gloo")
    return info, dev


def cleanup() -> None:
    """Leave the process group."""
    if dist.is_available() and dist.is_initialized():
        dist.destroy_process_group()


def average_gradients(params: Iterable[nn.Parameter]) -> None:
    """All-reduce the gradients of ``params`` to their mean over processes.

    Parameters without a gradient take part with zeros, so every process sends the
    same tensors in the same order.
    """
    if not (dist.is_available() and dist.is_initialized()):
        return
    world = dist.get_world_size()
    for p in params:
        if p.grad is None:
            p.grad = torch.zeros_like(p)
        dist.all_reduce(p.grad, op=dist.ReduceOp.SUM)
        p.grad.div_(world)


def broadcast_parameters(module: nn.Module, src: int = 0) -> None:
    """Copy ``src``'s parameters and buffers to every process."""
    if not (dist.is_available() and dist.is_initialized()):
        return
    for t in [*module.parameters(), *module.buffers()]:
        dist.broadcast(t.data, src)


def all_reduce_mean(values: Sequence[float], device: torch.device) -> list[float]:
    """Mean of some numbers over processes (for logging)."""
    if not (dist.is_available() and dist.is_initialized()):
        return list(values)
    t = torch.tensor(list(values), dtype=torch.float64, device=device)
    dist.all_reduce(t, op=dist.ReduceOp.SUM)
    return (t / dist.get_world_size()).tolist()


def shard(items: Sequence[T], info: DistInfo) -> list[T]:
    """This process's share of ``items`` (round-robin; all of them if too few)."""
    if len(items) < info.world_size:
        return list(items)
    return list(items[info.rank::info.world_size])
