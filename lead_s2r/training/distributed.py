"""The one collective evaluation callbacks need, and the end of a run's process group; no-ops when not distributed."""

from typing import Any

import torch.distributed as dist


def gather_lists(items: list[Any]) -> list[Any]:
    """Every rank's ``items`` concatenated in rank order, on every rank (picklable objects)."""
    if not (dist.is_available() and dist.is_initialized()) or dist.get_world_size() == 1:
        return items
    gathered: list[list[Any] | None] = [None] * dist.get_world_size()
    dist.all_gather_object(gathered, items)
    return [item for part in gathered for item in part or []]


def close_process_group() -> None:
    """Destroy the process group a finished run joined. Lightning does so only for NCCL; a gloo group (DDP on CPUs)
    left to the interpreter's exit can abort the process (SIGABRT, "terminate called without an active exception":
    its worker threads still hold tensors while Python is torn down), failing a run that trained to the end."""
    if dist.is_available() and dist.is_initialized():
        dist.destroy_process_group()
