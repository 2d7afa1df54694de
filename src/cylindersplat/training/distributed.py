"""Multi-process setup for ``torchrun``: one process per GPU, DistributedDataParallel.

Launched with ``WORLD_SIZE > 1`` in the environment (``torchrun --nproc_per_node=N ...``), the
trainer initialises the process group (NCCL on CUDA, Gloo on CPU), pins the process to
``cuda:$LOCAL_RANK`` and wraps the model in DDP. A plain ``python``/``cylindersplat`` run is a
world of one and needs none of it.
"""

from __future__ import annotations

import os
from dataclasses import dataclass

import torch
import torch.distributed as dist
from torch import nn

__all__ = ["DistInfo", "init_distributed", "wrap_ddp", "unwrap", "cleanup_distributed"]


@dataclass(frozen=True)
class DistInfo:
    rank: int = 0
    local_rank: int = 0
    world_size: int = 1

    @property
    def is_main(self) -> bool:
        return self.rank == 0

    @property
    def enabled(self) -> bool:
        return self.world_size > 1


def init_distributed(device: torch.device) -> tuple[DistInfo, torch.device]:
    world_size = int(os.environ.get("WORLD_SIZE", "1"))
    if world_size <= 1:
        return DistInfo(), device
    info = DistInfo(int(os.environ["RANK"]), int(os.environ.get("LOCAL_RANK", "0")), world_size)
    if device.type == "cuda":
        device = torch.device("cuda", info.local_rank)
        torch.cuda.set_device(device)
    if not dist.is_initialized():
        dist.init_process_group("nccl" if device.type == "cuda" else "gloo")
    return info, device


def wrap_ddp(model: nn.Module, info: DistInfo, device: torch.device) -> nn.Module:
    """Wrap for the current stage. DDP records which parameters require grad when it is built, so
    the trainer re-wraps after every curriculum switch; unused branches need find_unused_parameters."""
    if not info.enabled:
        return model
    ids = [device.index] if device.type == "cuda" else None
    return nn.parallel.DistributedDataParallel(model, device_ids=ids, find_unused_parameters=True)


def unwrap(model: nn.Module) -> nn.Module:
    return model.module if isinstance(model, nn.parallel.DistributedDataParallel) else model


def cleanup_distributed() -> None:
    if dist.is_initialized():
        dist.destroy_process_group()
