"""Robot-agnostic machinery of a batched Warp env: Warp start-up, devices, CPU shards, graph capture and replay
(torch's side of it is ``streams``: this module imports no torch, so that a command line is parsed without it).
Nothing here knows the cartpole; an env for another robot keeps it.
"""

from __future__ import annotations

import gc
import importlib
import logging
import os
import sys
import tempfile
import time
from collections.abc import Callable, Iterator
from concurrent.futures import ThreadPoolExecutor
from contextlib import contextmanager
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import warp as wp

from ..settings.config import ConfigError, check_device_name

if TYPE_CHECKING:
    from . import streams

logger = logging.getLogger("cartpole_warp")
"""The library's progress lines (INFO, e.g. that kernels compile): shown by train.py and play.py, silent in a library
use unless the application configures logging."""
MIN_ENVS_PER_SHARD = 512
"""Smallest shard worth its own scene and thread on the CPU."""
_NO_DRIVER_WARNING = b"Could not find or load the NVIDIA CUDA driver"


def init_warp() -> None:
    """``wp.init()`` without the warning Warp's native library prints on every machine without an NVIDIA driver
    (it writes straight to file descriptor 2, so it is filtered there); every other line passes. Changes no Warp
    setting; once Warp is initialised it prints nothing more."""
    sys.stderr.flush()
    try:
        saved = os.dup(2)
    except OSError:  # no usable file descriptor 2: nothing to filter
        wp.init()
        return
    with tempfile.TemporaryFile() as captured:
        os.dup2(captured.fileno(), 2)
        try:
            wp.init()
        finally:
            sys.stderr.flush()
            os.dup2(saved, 2)
            os.close(saved)
        captured.seek(0)
        kept = [line for line in captured.read().splitlines(keepends=True) if _NO_DRIVER_WARNING not in line]
    if kept:
        os.write(2, b"".join(kept))


@contextmanager
def warp_output(verbose: bool) -> Iterator[None]:
    """Inside: Warp's info lines (its greeting, a line per module loaded or compiled) off, or on where ``verbose``;
    Warp's own setting is restored after (the library changes no global setting)."""
    level = wp.config.log_level
    wp.config.log_level = min(level, wp.LOG_INFO) if verbose else max(level, wp.LOG_WARNING)
    try:
        yield
    finally:
        wp.config.log_level = level


def compile_without_adjoints(*names: str) -> None:
    """Warp's ``enable_backward`` option off on the named modules alone (imported first, so that their kernels are
    registered): code that nothing here differentiates compiles faster without its adjoint (docs/benchmarks.md);
    other modules and Warp's global setting keep theirs."""
    for name in names:
        module = wp.get_module(importlib.import_module(name).__name__)
        if module.options.get("enable_backward") is not False:
            wp.set_module_options({"enable_backward": False}, module=module)


def cached(module: wp.Module, device: str) -> bool:
    """Whether Warp's kernel cache holds ``module`` (as it is now, options included) built for ``device``'s kind of
    launch: loading it then compiles nothing."""
    block_dim = 1 if device == "cpu" else module.options["block_dim"]
    return os.path.isdir(os.path.join(wp.config.kernel_cache_dir, module.get_module_identifier(block_dim)))


def load_modules(modules: list[wp.Module], device: str, what: str) -> None:
    """Load ``modules`` on ``device`` now, compiling those the kernel cache lacks in parallel (Warp's compiler releases
    the GIL), so that nothing compiles later inside a step; logs one line (logger ``cartpole_warp``, INFO) before it
    compiles. ``what`` names them in that line."""
    missing = [module for module in modules if not cached(module, device)]
    if missing:
        logger.info("compiling Warp kernels for %s on %s (first run with this code on this machine; cached in %s): "
                    "%d modules ...", what, device, wp.config.kernel_cache_dir, len(missing))
    wp.force_load(device=device, modules=modules, max_workers=max(1, min(len(missing), len(os.sched_getaffinity(0)))))


NO_CUDA = "device {!r} requested but no CUDA device is available here; use --device cpu"
"""The error for a CUDA device on a machine without one (``NO_CUDA.format(device)``)."""


def free_memory_bytes(device: str) -> int:
    """Memory free for new buffers: the host's available memory for 'cpu', else the CUDA device's free memory."""
    if device == "cpu":
        return os.sysconf("SC_AVPHYS_PAGES") * os.sysconf("SC_PAGE_SIZE")
    return wp.get_device(device).free_memory


def resolve_device(device: str) -> str:
    """'cpu' or 'cuda:N' from 'cpu', 'cuda' or 'cuda:N'; ConfigError if it does not exist here."""
    import torch

    check_device_name(device)
    init_warp()
    name = "cuda:0" if str(device) == "cuda" else str(device)
    if name == "cpu":
        return name
    if not wp.is_cuda_available() or not torch.cuda.is_available():
        raise ConfigError(NO_CUDA.format(device))
    if int(name[5:]) >= wp.get_cuda_device_count():
        raise ConfigError(f"device {device!r} requested but only {wp.get_cuda_device_count()} CUDA device(s) exist")
    return name


def shard_bounds(num_envs: int, device: str, cpu_threads: int, shardable: bool = True) -> list[tuple[int, int]]:
    """[start, stop) env ranges simulated as separate scenes. On the CPU (where Warp runs each kernel launch on one
    thread) one per thread (``cpu_threads``, 0 = the available cores), each of at least MIN_ENVS_PER_SHARD envs;
    on CUDA, or when the solver cannot be sharded, one."""
    if device != "cpu" or not shardable:
        return [(0, num_envs)]
    threads = cpu_threads or len(os.sched_getaffinity(0))
    count = max(1, min(threads, num_envs // MIN_ENVS_PER_SHARD))
    edges = [num_envs * k // count for k in range(count + 1)]
    return list(zip(edges[:-1], edges[1:]))


@dataclass
class Shard:
    """The envs [start, stop) and the scene that simulates them."""

    index: int
    start: int
    stop: int
    scene: Any

    @property
    def num_envs(self) -> int:
        return self.stop - self.start

    def rows(self, array: wp.array) -> wp.array:
        """The shard's rows of a per-env buffer (a view)."""
        return array[self.start:self.stop]

    def slot(self, counters: wp.array) -> wp.array:
        """The shard's own element of a per-shard counter (a view)."""
        return counters[self.index:self.index + 1]


@contextmanager
def timed(seconds: dict[str, float], phase: str) -> Iterator[None]:
    """Add the wall-clock seconds of the ``with`` block to ``seconds[phase]`` (host time: what a user waits)."""
    start = time.perf_counter()
    try:
        yield
    finally:
        seconds[phase] = seconds.get(phase, 0.0) + time.perf_counter() - start


class GraphReplay:
    """Replays one captured graph per shard: in the calling thread for one, concurrently for several (Warp replays
    a CPU graph in one native call that releases the GIL, so the shards use separate cores)."""

    def __init__(self, graphs: list):
        self.graphs = graphs
        self._pool = ThreadPoolExecutor(len(graphs), thread_name_prefix="cartpole-shard") if len(graphs) > 1 else None

    def __call__(self):
        if self._pool is None:
            wp.capture_launch(self.graphs[0])
        else:
            for _ in self._pool.map(wp.capture_launch, self.graphs):
                pass

    def close(self):
        if self._pool is not None:
            self._pool.shutdown()


@contextmanager
def collection_paused() -> Iterator[None]:
    """Python's cyclic garbage collector off inside (as it was after): a CUDA graph it frees during a capture (an ended
    run's, held by a reference cycle: a second training in one process) breaks the capture and ends the process
    (``CUDAGraph.reset`` is not permitted while a stream captures). torch no longer collects before a capture
    (``torch.compiler.config.force_cudagraph_gc``), and Warp never did; every capture here runs inside this."""
    enabled = gc.isenabled()
    gc.disable()
    try:
        yield
    finally:
        if enabled:
            gc.enable()


class ShardedStep:
    """``step_fn(shard)`` for every shard: captured once per shard and replayed (``capture=True``), or launched.

    Whatever ``step_fn`` launches must only overwrite persistent arrays: a captured graph holds their pointers."""

    def __init__(self, shards: list[Shard], step_fn: Callable[[Shard], None], order: streams.StreamOrder,
                 capture: bool):
        self.shards, self.step_fn, self.order = shards, step_fn, order
        self.replay = None
        if capture:
            graphs = []
            for shard in shards:
                with order, collection_paused(), wp.ScopedCapture(device=shard.scene.model.device) as captured:
                    step_fn(shard)
                graphs.append(captured.graph)
            self.replay = GraphReplay(graphs)

    def __call__(self):
        with self.order:
            if self.replay is not None and not self.order.capturing():
                self.replay()
            else:
                for shard in self.shards:
                    self.step_fn(shard)

    def close(self):
        """Stop the replay threads."""
        if self.replay is not None:
            self.replay.close()
