"""Multi-process training with DistributedDataParallel, started by ``torchrun``.

``torchrun --nproc-per-node N -m scotti.cli.main train ...`` starts N copies
of ``scotti train`` and tells each its place through the environment
(RANK, WORLD_SIZE, LOCAL_RANK, MASTER_ADDR/PORT). Each copy plans the same
epoch (the plan is a pure function of seed and epoch) and takes every N-th
batch of it; DDP averages the gradients, so a step trains on N batches and
an epoch has 1/N of the steps. Rank 0 alone writes checkpoints, history
and logs, and runs validation; the others wait for its result, so every
decision (best, plateau, stop) is taken on the same numbers everywhere.

Backend: gloo on CPU, nccl on CUDA (one GPU per process, GPU = LOCAL_RANK).
Without WORLD_SIZE (a plain ``scotti train``) nothing here starts a
process group and every helper is a no-op.
"""

from __future__ import annotations

import os
from collections.abc import Iterator, Sequence
from contextlib import contextmanager
from dataclasses import dataclass
from datetime import timedelta
from typing import Any, TypeVar

import torch
import torch.distributed as dist
from scotti.export.errors import ExportError

Item = TypeVar("Item")

# Ranks wait for rank 0 while it validates and writes checkpoints: a long
# validation must not look like a dead peer (torch's nccl default is 10 min).
COLLECTIVE_TIMEOUT = timedelta(hours=2)


class DistributedError(ExportError):
    """A torchrun environment that does not add up (one-line message)."""


@dataclass(frozen=True)
class DistContext:
    rank: int = 0
    world_size: int = 1
    local_rank: int = 0

    @property
    def distributed(self) -> bool:
        return self.world_size > 1

    @property
    def is_main(self) -> bool:
        return self.rank == 0


def context_from_environment(env: dict[str, str] | None = None) -> DistContext:
    """RANK, WORLD_SIZE, LOCAL_RANK as torchrun sets them; a single process without them."""
    env = dict(os.environ if env is None else env)
    try:
        world = int(env.get("WORLD_SIZE", "1"))
        rank = int(env.get("RANK", "0"))
        local = int(env.get("LOCAL_RANK", str(rank)))
    except ValueError:
        msg = "RANK, WORLD_SIZE and LOCAL_RANK must be integers (torchrun sets them)"
        raise DistributedError(msg) from None
    if world < 1 or not 0 <= rank < world or local < 0:
        msg = f"rank {rank} of world size {world} (local rank {local}) does not add up"
        raise DistributedError(msg)
    return DistContext(rank=rank, world_size=world, local_rank=local)


@contextmanager
def process_group(ctx: DistContext, device: torch.device) -> Iterator[None]:
    """The process group for this run (gloo on CPU, nccl on CUDA), torn down at the end."""
    if not ctx.distributed:
        yield
        return
    backend = "nccl" if device.type == "cuda" else "gloo"
    dist.init_process_group(
        backend,
        rank=ctx.rank,
        world_size=ctx.world_size,
        timeout=COLLECTIVE_TIMEOUT,
        device_id=device if device.type == "cuda" else None,
    )
    try:
        yield
    except BaseException:
        dist.destroy_process_group()  # no barrier: a peer may be gone, it would hang
        raise
    # Every rank done with every collective before any tears its group down, so
    # no rank closes its connections while a peer is still in one. (A rank that
    # fails is not waited for: torchrun stops the others when one exits non-zero.)
    dist.barrier()
    dist.destroy_process_group()


def shard(batches: Sequence[Item], ctx: DistContext) -> list[Item]:
    """This rank's share of an epoch: every world_size-th batch from its rank on.

    Every rank gets the same number of batches (DDP steps in lock-step), so the
    last ``len % world_size`` batches of the plan are left out; the plan is
    reshuffled every epoch, so it is not the same windows that miss out.
    """
    per_rank = len(batches) // ctx.world_size
    return list(batches[ctx.rank : per_rank * ctx.world_size : ctx.world_size])


def _collective_device(device: torch.device) -> torch.device:
    # nccl reduces tensors on the GPU, gloo on the CPU.
    return device if device.type == "cuda" else torch.device("cpu")


def all_sum(values: Sequence[float], ctx: DistContext, device: torch.device) -> list[float]:
    """Element-wise sum over all ranks (float64); the values themselves in one process."""
    if not ctx.distributed:
        return list(values)
    t = torch.tensor(values, dtype=torch.float64, device=_collective_device(device))
    dist.all_reduce(t, op=dist.ReduceOp.SUM)
    return [float(v) for v in t.tolist()]


def any_rank(flag: bool, ctx: DistContext, device: torch.device) -> bool:
    """True on every rank if it is true on any (for example: time is up on one of them)."""
    return all_sum([1.0 if flag else 0.0], ctx, device)[0] > 0


def from_main(obj: Any, ctx: DistContext) -> Any:
    """Rank 0's ``obj`` on every rank (pickled); ``obj`` elsewhere is ignored."""
    if not ctx.distributed:
        return obj
    box = [obj if ctx.is_main else None]
    dist.broadcast_object_list(box, src=0)
    return box[0]


def gather(obj: Any, ctx: DistContext) -> list[Any]:
    """Every rank's ``obj``, in rank order, on every rank."""
    if not ctx.distributed:
        return [obj]
    out: list[Any] = [None] * ctx.world_size
    dist.all_gather_object(out, obj)
    return out


def barrier(ctx: DistContext) -> None:
    if ctx.distributed:
        dist.barrier()


def sync_buffers(module: torch.nn.Module, ctx: DistContext) -> None:
    """Rank 0's buffers (batch-norm running statistics) on every rank.

    DDP hands rank 0's buffers to all ranks at the start of each forward pass,
    but the pass itself then updates each rank's copy from its own batch; after
    the last step they differ until synced here.
    """
    if not ctx.distributed:
        return
    for buffer in module.buffers():
        dist.broadcast(buffer, src=0)


def wrap(module: torch.nn.Module, ctx: DistContext, device: torch.device) -> torch.nn.Module:
    """``module`` under DDP when there are several ranks (on the GPU of this rank)."""
    if not ctx.distributed:
        return module
    from torch.nn.parallel import DistributedDataParallel

    ids = [device.index] if device.type == "cuda" else None
    return DistributedDataParallel(module, device_ids=ids)


def unwrap(module: torch.nn.Module) -> torch.nn.Module:
    """The module inside ``wrap``'s DDP (``module`` itself when it is not one)."""
    from torch.nn.parallel import DistributedDataParallel

    return module.module if isinstance(module, DistributedDataParallel) else module
