"""Data-parallel training under ``torchrun``: process-group set-up and tear-down (gloo, CPU), shared by
``gvnn-warp vo`` and ``gvnn-warp depth train``. Without ``WORLD_SIZE`` > 1 everything is a no-op. A process
group that the caller has already made (a script that trains more than one thing under one ``torchrun``)
is joined and left up; the one made here is torn down by :func:`finish`."""

from __future__ import annotations

import os

import torch
import torch.distributed as dist

__all__ = ["all_max", "average_gradients", "finish", "setup"]

_OWN_GROUP = False  # the process group was made by setup() (and so is torn down by finish())


def setup() -> tuple[int, int]:
    """(rank, world size): the process group of ``torchrun`` (``RANK``/``WORLD_SIZE``), made here unless
    the caller made one."""
    global _OWN_GROUP
    world = int(os.environ.get("WORLD_SIZE", "1"))
    _OWN_GROUP = world > 1 and not dist.is_initialized()  # (joining a caller's group: never ours to tear down)
    if _OWN_GROUP:
        dist.init_process_group("gloo")
    if dist.is_initialized():
        return dist.get_rank(), dist.get_world_size()
    return 0, 1


def all_max(value: float, world: int) -> float:
    """The largest ``value`` over the ranks (e.g. a stop flag every rank must agree on)."""
    if world <= 1:
        return float(value)
    t = torch.tensor([float(value)], dtype=torch.float64)
    dist.all_reduce(t, op=dist.ReduceOp.MAX)
    return float(t.item())


def average_gradients(module: torch.nn.Module, world: int) -> None:
    """Average ``module``'s gradients over the ranks (for a network whose forward does not run through
    a DistributedDataParallel wrapper, e.g. one called through another method)."""
    if world <= 1:
        return
    for p in module.parameters():
        if p.grad is None:
            p.grad = torch.zeros_like(p)
        dist.all_reduce(p.grad)
        p.grad /= world


def finish(world: int) -> None:
    """Wait for every rank, then tear the process group down if :func:`setup` made it."""
    global _OWN_GROUP
    if world > 1 and dist.is_initialized():
        dist.barrier()
        if _OWN_GROUP:
            dist.destroy_process_group()
            _OWN_GROUP = False
