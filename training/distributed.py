"""Data-parallel training across processes (``torchrun``): process group, rank roles, the DDP wrapper.

``torchrun --nproc-per-node N -m demo train ...`` (or ``demo train ... --nproc N``, :func:`launch`)
starts N copies of the same command with ``RANK``, ``WORLD_SIZE``, ``LOCAL_RANK``, ``MASTER_ADDR``
and ``MASTER_PORT`` set. :func:`init_from_env` joins them into one process group (gloo on the CPU,
NCCL on CUDA, one GPU per local rank). Under torchrun even a world of one joins its group (one GPU
runs the same NCCL path as eight); a plain ``demo train``, outside torchrun, never touches
``torch.distributed``.

Roles: every rank samples its own batches and computes gradients, which DDP averages (an all-reduce
in ``backward``), so the weights stay identical on every rank. Rank 0 alone writes the run directory
(``run.json``, checkpoints, metrics, curves), validates, rolls out and reports progress.

Batch and learning rate: ``--batch-size`` is per rank, so a step averages gradients over
``N x batch_size`` windows; the learning rate and its schedule (in optimiser steps) are unchanged.
"""

from __future__ import annotations

import os
import subprocess
import sys
from dataclasses import dataclass
from datetime import timedelta

import torch
import torch.distributed as dist

from demo.policies.policy import Policy


@dataclass(frozen=True)
class Group:
    """This process's place in a data-parallel run."""

    rank: int  # 0 .. world - 1; 0 writes the run directory
    world: int  # processes in the run (1 under ``torchrun --nproc-per-node 1``)
    local_rank: int  # index on this machine: the GPU it uses

    @property
    def is_main(self) -> bool:
        return self.rank == 0


def env_world_size() -> int:
    """``WORLD_SIZE`` as torchrun sets it (1 outside torchrun)."""
    return int(os.environ.get("WORLD_SIZE", "1") or 1)


def is_main_process() -> bool:
    """Whether this process reports (rank 0, or not under torchrun at all): for the CLI's output."""
    return int(os.environ.get("RANK", "0") or 0) == 0


def under_torchrun() -> bool:
    """Whether torchrun started this process (it sets the rendezvous variables, also for one process)."""
    return all(name in os.environ for name in ("RANK", "WORLD_SIZE", "MASTER_ADDR", "MASTER_PORT"))


def init_from_env(device: torch.device) -> tuple[Group | None, torch.device]:
    """Join torchrun's process group (None outside torchrun) and the device this rank trains on:
    NCCL and ``cuda:LOCAL_RANK`` for a CUDA device, gloo and ``device`` otherwise."""
    if not under_torchrun():
        return None, device
    group = Group(int(os.environ["RANK"]), env_world_size(), int(os.environ.get("LOCAL_RANK", "0")))
    if device.type == "cuda":
        device = torch.device("cuda", group.local_rank)
        torch.cuda.set_device(device)
    if not dist.is_initialized():
        # Rank 0 may roll the policy out mid-run while the others wait in the gradient all-reduce.
        dist.init_process_group("nccl" if device.type == "cuda" else "gloo", timeout=timedelta(hours=2))
    return group, device


class PolicyLoss(torch.nn.Module):
    """A policy whose forward is its training loss, so DDP's forward runs :meth:`Policy.loss` (DDP
    hooks the gradients of what its wrapped module's forward computed)."""

    def __init__(self, policy: Policy):
        super().__init__()
        self.policy = policy

    def forward(self, *batch: torch.Tensor) -> torch.Tensor:
        return self.policy.loss(*batch)


def wrap(policy: Policy, device: torch.device) -> torch.nn.Module:
    """``policy``'s loss under DistributedDataParallel (rank 0's weights broadcast to all ranks);
    the policy itself stays the module that is checkpointed and evaluated."""
    ids = [device.index] if device.type == "cuda" else None
    return torch.nn.parallel.DistributedDataParallel(PolicyLoss(policy), device_ids=ids)


def mean(value: float, group: Group | None) -> float:
    """The mean of ``value`` over every rank (itself without a group): one number every rank agrees on."""
    if group is None:
        return value
    t = torch.tensor([value], dtype=torch.float64)
    if dist.get_backend() == "nccl":
        t = t.cuda()
    dist.all_reduce(t)
    return float(t.item()) / group.world


def backend() -> str:
    """The process group's backend: ``nccl`` on CUDA, ``gloo`` on the CPU."""
    return str(dist.get_backend())


def barrier(group: Group | None) -> None:
    """Wait for every rank (nothing without a group)."""
    if group is not None:
        dist.barrier()


def shutdown(group: Group | None) -> None:
    """Leave the process group (nothing without one)."""
    if group is not None and dist.is_initialized():
        dist.destroy_process_group()


def launch(args: list[str], nproc: int) -> int:
    """Run ``demo ARGS`` as ``nproc`` torchrun processes on this machine (a free port found by
    torchrun's standalone rendezvous); returns their exit code."""
    command = [sys.executable, "-m", "torch.distributed.run", "--standalone", f"--nproc-per-node={nproc}",
               "-m", "demo", *args]
    # torchrun would set one thread per process anyway, with a banner saying so: --threads decides.
    env = {"OMP_NUM_THREADS": "1", **os.environ}
    return subprocess.run(command, check=False, env=env).returncode
