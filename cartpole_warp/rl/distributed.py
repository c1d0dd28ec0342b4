"""Training on several GPUs, started by torchrun: which GPU and seed each process takes, who writes, and decisions
all processes take together.

    torchrun --nproc_per_node=2 train.py --device cuda --num-envs 4096      # 4096 envs on each GPU

rsl-rl does the data-parallel PPO itself (``OnPolicyRunner`` reads ``WORLD_SIZE``/``RANK``/``LOCAL_RANK``, creates the
NCCL process group, broadcasts the parameters from rank 0, all-reduces the gradients); this module adds the rest:
``cuda:$LOCAL_RANK`` and seed + rank per process, one run folder written by rank 0 alone, episode statistics summed
over all processes, and one stop decision for all of them. A population (``train.py --seeds``) spreads its members
over the processes instead: each trains its share, and rank 0 writes the population's table.

    torchrun --nproc_per_node=2 train.py --device cuda --seeds 0 1 2 3 4 5 6 7          # four members on each GPU
"""

from __future__ import annotations

import dataclasses
import os
from collections.abc import Mapping
from dataclasses import dataclass

from ..settings.config import ConfigError, EnvConfig

STOP_REASONS = (None, "solved", "interrupted")
"""Stop decisions by code; the all-reduce takes the largest, so an interruption anywhere wins over solved."""


@dataclass(frozen=True)
class Ranks:
    """This process's place in a torchrun job; one process alone when not started by torchrun."""

    world_size: int = 1
    rank: int = 0
    local_rank: int = 0

    @classmethod
    def from_environment(cls, environ: Mapping[str, str] = os.environ) -> Ranks:
        """From torchrun's ``WORLD_SIZE``, ``RANK`` and ``LOCAL_RANK``."""
        try:
            return cls(int(environ.get("WORLD_SIZE", "1")), int(environ.get("RANK", "0")),
                       int(environ.get("LOCAL_RANK", "0")))
        except ValueError:
            raise ConfigError("WORLD_SIZE, RANK and LOCAL_RANK must be integers (torchrun sets them)") from None

    @property
    def distributed(self) -> bool:
        return self.world_size > 1

    @property
    def writes(self) -> bool:
        """Whether this process writes the run folder and prints progress: rank 0 alone."""
        return self.rank == 0

    def env_config(self, env: EnvConfig, cuda_devices: int) -> EnvConfig:
        """``env`` for this process: on ``cuda:$LOCAL_RANK`` with seed + rank when distributed, else unchanged.
        ConfigError for a CPU device or more processes on this host than it has GPUs."""
        if not self.distributed:
            return env
        if not env.device.startswith("cuda"):
            raise ConfigError(f"training on {self.world_size} processes (torchrun) needs --device cuda, got "
                              f"{env.device!r}; run a single process for the CPU")
        return dataclasses.replace(env, device=self.device(env.device, cuda_devices), seed=env.seed + self.rank)

    def device(self, device: str, cuda_devices: int) -> str:
        """This process's device for ``device``: ``cuda:$LOCAL_RANK`` for a CUDA device when distributed (ConfigError
        where the host has fewer GPUs than processes), else ``device``."""
        if not self.distributed or not device.startswith("cuda"):
            return device
        if cuda_devices == 0:
            raise ConfigError(f"training on {self.world_size} processes (torchrun) needs a CUDA GPU per process, but "
                              "torch sees no GPU on this host; run a single process with --device cpu instead")
        if self.local_rank >= cuda_devices:
            raise ConfigError(f"process {self.local_rank} of this host needs cuda:{self.local_rank}, but the host has "
                              f"{cuda_devices} CUDA device(s): start at most {cuda_devices} processes per node")
        return f"cuda:{self.local_rank}"

    def share(self, items: list) -> list:
        """This process's consecutive share of ``items`` (shares differ in length by at most one; ConfigError where
        there are fewer items than processes)."""
        if len(items) < self.world_size:
            raise ConfigError(f"{len(items)} members cannot be spread over {self.world_size} processes (torchrun): "
                              "each process needs at least one")
        return items[self.rank * len(items) // self.world_size:(self.rank + 1) * len(items) // self.world_size]


SINGLE_PROCESS = Ranks()
"""A process not started by torchrun."""


def join_process_group(ranks: Ranks, device: str, backend: str = "nccl") -> dict | None:
    """rsl-rl's ``multi_gpu`` config of this process once it has joined torchrun's process group on ``device`` (this
    process's): NCCL for a run whose processes all-reduce gradients (on ``cuda:$LOCAL_RANK``: what rsl-rl's
    ``OnPolicyRunner`` does as it starts), gloo for a population's, on any device (its members exchange no gradients,
    only their run folder's name at the start and their table rows at the end). None for a process alone."""
    if not ranks.distributed:
        return None
    if backend == "nccl" and device != f"cuda:{ranks.local_rank}":
        raise ConfigError(f"process {ranks.rank} of a torchrun job trains on cuda:{ranks.local_rank}, not {device}")
    import torch

    torch.distributed.init_process_group(backend=backend, rank=ranks.rank, world_size=ranks.world_size)
    if device.startswith("cuda"):
        torch.cuda.set_device(device)
    return {"global_rank": ranks.rank, "local_rank": ranks.local_rank, "world_size": ranks.world_size}


def from_rank_zero(value, ranks: Ranks):
    """Rank 0's ``value`` in every process (a process alone keeps its own)."""
    if not ranks.distributed:
        return value
    import torch

    holder = [value]
    torch.distributed.broadcast_object_list(holder, src=0)
    return holder[0]


def from_every_rank(value, ranks: Ranks) -> list:
    """Every process's ``value``, by rank, in every process."""
    if not ranks.distributed:
        return [value]
    import torch

    values = [None] * ranks.world_size
    torch.distributed.all_gather_object(values, value)
    return values


def joint_stop(wanted: str | None, device: str, distributed: bool) -> str | None:
    """The stop decision of all processes from this one's wish (a ``STOP_REASONS`` entry): the strongest wish of any
    process (the all-reduced largest code); a process alone decides by itself, without touching the device."""
    if not distributed:
        return wanted
    import torch  # only under torchrun: this module is imported before the command line is parsed

    code = torch.tensor([STOP_REASONS.index(wanted)], device=device)
    torch.distributed.all_reduce(code, op=torch.distributed.ReduceOp.MAX)
    return STOP_REASONS[int(code.item())]
