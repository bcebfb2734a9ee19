"""Processes and parallelism in one place (torchtitan's ``parallelize``): the loop and the model know nothing of it.

Under ``torchrun`` (``RANK``/``WORLD_SIZE``/``MASTER_ADDR`` set) the process
group is started with gloo on CPU and NCCL on CUDA. ``wrap`` applies:

* ``ddp``: ``DistributedDataParallel`` (gradients all-reduced, averaged);
* ``fsdp``: FSDP2, ``fully_shard`` on every transformer block, then on the
  root (parameters, gradients and optimiser state sharded across ranks;
  works on CPU with gloo in torch 2.13, tested with 2 processes);
* ``none``: the module as is.
"""

from __future__ import annotations

import contextlib
import os
from dataclasses import dataclass

import torch
import torch.distributed as dist

__all__ = [
    "DistInfo",
    "init_distributed",
    "close_distributed",
    "wrap_model",
    "no_sync",
    "barrier",
    "all_reduce_mean",
    "all_reduce_sum",
    "any_rank_samples",
]


@dataclass(frozen=True)
class DistInfo:
    """rank, world size, local rank, the device this process trains on, and whether a process group exists."""

    rank: int = 0
    world: int = 1
    local_rank: int = 0
    device: torch.device = torch.device("cpu")
    distributed: bool = False

    @property
    def main(self) -> bool:
        return self.rank == 0


def init_distributed(device: str | None = None) -> DistInfo:
    """Start the process group when launched by torchrun (else a single process)."""
    world = int(os.environ.get("WORLD_SIZE", "1"))
    rank, local = int(os.environ.get("RANK", "0")), int(os.environ.get("LOCAL_RANK", "0"))
    cuda = torch.cuda.is_available() if device is None else str(device).startswith("cuda")
    dev = torch.device(f"cuda:{local}") if cuda else torch.device("cpu")
    if cuda:
        torch.cuda.set_device(dev)
    if world > 1 and not dist.is_initialized():
        dist.init_process_group("nccl" if cuda else "gloo")
    return DistInfo(rank, world, local, dev, world > 1)


def close_distributed(info: DistInfo) -> None:
    if info.distributed and dist.is_initialized():
        dist.destroy_process_group()


def wrap_model(model: torch.nn.Module, mode: str, info: DistInfo) -> torch.nn.Module:
    """Apply the parallelism ``mode`` ("auto", "none", "ddp", "fsdp"); "auto" is DDP on several processes."""
    if mode == "auto":
        mode = "ddp" if info.world > 1 else "none"
    if mode == "none" or (mode == "ddp" and not info.distributed):
        return model
    if not info.distributed:
        if mode == "fsdp":
            from .config import TrainConfigError

            raise TrainConfigError(
                "<config>",
                "parallel",
                "'fsdp' under a torchrun launch of several processes (or 'none' / 'auto' for one process)",
                "'fsdp' in a single process",
            )
        return model
    if mode == "ddp":
        from torch.nn.parallel import DistributedDataParallel

        return DistributedDataParallel(model, device_ids=[info.device.index] if info.device.type == "cuda" else None)
    if mode == "fsdp":
        from torch.distributed.fsdp import fully_shard

        for block in model.transformer_blocks:
            fully_shard(block)
        fully_shard(model)
        return model
    raise ValueError(f"parallel: expected 'auto', 'none', 'ddp' or 'fsdp', found {mode!r}")


@contextlib.contextmanager
def no_sync(model: torch.nn.Module, sync: bool):
    """Skip the gradient all-reduce (DDP) / reduce-scatter (FSDP2) on accumulation micro-steps."""
    from torch.nn.parallel import DistributedDataParallel

    if sync:
        yield
        return
    if isinstance(model, DistributedDataParallel):
        with model.no_sync():
            yield
        return
    if hasattr(model, "set_requires_gradient_sync"):  # FSDP2
        model.set_requires_gradient_sync(False)
        try:
            yield
        finally:
            model.set_requires_gradient_sync(True)
        return
    yield


def barrier(info: DistInfo) -> None:
    if info.distributed:
        dist.barrier()


def all_reduce_sum(value: float, info: DistInfo) -> float:
    """Sum of a float over ranks (float64: exact for counts)."""
    if not info.distributed:
        return float(value)
    t = torch.tensor([float(value)], dtype=torch.float64)
    dist.all_reduce(t)
    return float(t.item())


def all_reduce_mean(value: float, info: DistInfo) -> float:
    """Mean of a float over ranks."""
    return all_reduce_sum(value, info) / (info.world if info.distributed else 1)


def any_rank_samples(mine: bool, config) -> bool:
    """Whether any process of a sharded (FSDP2) run has something to sample this micro-batch (``mine`` for one
    process, or a run without sharded weights, where each process samples on its own): FSDP2 gathers the weights
    in every forward, so each process must run one when any does."""
    if config.parallel != "fsdp" or not (dist.is_available() and dist.is_initialized()):
        return mine
    flag = torch.tensor([int(mine)])
    dist.all_reduce(flag, op=dist.ReduceOp.MAX)
    return bool(flag.item())
