"""Data-parallel training under `torchrun` (docs/scaling.md): which rank this process is, the process group,
each rank's share of a batch, and the few collectives the training loop and the engine need.

A process started by `torchrun --nproc-per-node N` (N > 1) sees WORLD_SIZE, RANK and LOCAL_RANK; every
other process is a single-process run, for which every function here is the identity (no process group,
no communication), so those runs are bit-identical to fftool without this module.

The batch rule: the single-process batch stays the global batch. Every rank draws the same epoch plan
(same seeds), builds the same global batch and keeps windows rank::N of it; its mean loss is scaled by
N · n_rank / n_global, so DistributedDataParallel's average of the ranks' gradients is exactly the
gradient of the global batch's mean loss. The learning rate and schedule therefore stay as configured.
"""

from __future__ import annotations

import atexit
import datetime
import os
from typing import Any

import numpy as np
import torch
import torch.distributed as dist
from torch.nn.parallel import DistributedDataParallel

# Collectives wait this long for the other ranks: rank 0 alone validates, re-hashes inputs and installs the
# artifact while the others wait (torchrun stops every rank as soon as one fails, so this only bounds a hang).
TIMEOUT = datetime.timedelta(hours=2)
_RANK_STRIDE = 2**40  # a rank's seeds are the single-process seeds + rank · this: no two ranks or epochs collide


def world_size() -> int:
    """How many ranks train together (1: a single-process run)."""
    return int(os.environ.get("WORLD_SIZE", "1"))


def active() -> bool:
    """Whether this process is one of several torchrun ranks."""
    return world_size() > 1


def rank() -> int:
    return int(os.environ.get("RANK", "0")) if active() else 0


def leader() -> bool:
    """Rank 0: the one rank that writes (checkpoints, logs, the artifact) and prints."""
    return rank() == 0


def join(device_name: str = "auto") -> None:
    """Join the process group once (no-op for a single process): nccl when this rank trains on CUDA, gloo
    on CPU. `device_name` is the command's --device (auto | cpu | cuda)."""
    if not active() or dist.is_initialized():
        return
    cuda = device_name != "cpu" and torch.cuda.is_available()
    if cuda:
        torch.cuda.set_device(int(os.environ.get("LOCAL_RANK", "0")))
    dist.init_process_group("nccl" if cuda else "gloo", timeout=TIMEOUT)
    atexit.register(leave)


def backend() -> str | None:
    """The process group's backend (None for a single process)."""
    return dist.get_backend() if active() and dist.is_initialized() else None


def device(chosen: torch.device) -> torch.device:
    """The device of this rank: its own GPU (LOCAL_RANK) when `chosen` is CUDA; joins the group first."""
    join(chosen.type)
    if active() and chosen.type == "cuda":
        return torch.device("cuda", int(os.environ.get("LOCAL_RANK", "0")))
    return chosen


def rank_seed(seed: int) -> int:
    """The seed of this rank's own random draws (rotations, latent samples, dropout); `seed` on rank 0."""
    return seed + rank() * _RANK_STRIDE


def shard(members: np.ndarray) -> tuple[np.ndarray, float]:
    """This rank's windows of a global batch (positions in `members`) and the factor of its mean loss.

    Windows rank::N; the factor N · n_rank / n_global makes the ranks' averaged gradients the gradient of the
    global batch's mean. A rank left without a window (a batch of fewer windows than ranks) gets the first
    one with factor 0: it still runs forward and backward, as DDP needs, and adds nothing.
    """
    n, size = len(members), world_size()
    mine = np.arange(rank(), n, size)
    if not len(mine):
        return np.arange(1), 0.0
    return mine, size * len(mine) / n


def wrap(module: torch.nn.Module, chosen: torch.device) -> torch.nn.Module:
    """`module` in DistributedDataParallel (gradients averaged over ranks during backward), or itself."""
    if not active():
        return module
    return DistributedDataParallel(module, device_ids=[chosen.index] if chosen.type == "cuda" else None)


def broadcast(value: Any) -> Any:
    """Rank 0's `value` (any picklable object) on every rank; `value` itself for a single process."""
    if not active():
        return value
    box = [value]
    dist.broadcast_object_list(box, src=0)
    return box[0]


def sum_over_ranks(values: dict[str, float], chosen: torch.device) -> dict[str, float]:
    """Each entry summed over the ranks (float64); `values` itself for a single process."""
    if not active():
        return values
    total = torch.tensor(list(values.values()), dtype=torch.float64, device=chosen)
    dist.all_reduce(total)
    return dict(zip(values, total.tolist()))


def barrier() -> None:
    if active():
        dist.barrier()


def leave() -> None:
    """Leave the process group (the end of a torchrun command)."""
    if active() and dist.is_initialized():
        dist.destroy_process_group()
