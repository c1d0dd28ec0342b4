"""torch's side of the env machinery on CUDA: the order of torch and Warp work on their streams, torch's CUDA graphs
(with Warp kernels in them), and GPU timing. ``runtime`` holds the rest and imports no torch; this module is imported
when an env is built.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from typing import Any

import torch
import warp as wp

from ..settings.deprecation import renamed
from .runtime import collection_paused


def check_tensor(name: str, value: Any, shapes: tuple, dtype: torch.dtype, device: str) -> torch.Tensor:
    """``value`` if it is a tensor of one of ``shapes``, of ``dtype``, on ``device``; else ValueError naming ``name``,
    what was expected and what came."""
    shape = " or ".join(str(tuple(s)) for s in shapes)
    expected = f"a torch.Tensor of shape {shape}, dtype {dtype}, on {device}"
    if not isinstance(value, torch.Tensor):
        raise ValueError(f"{name}: expected {expected}; got {type(value).__name__}")
    if tuple(value.shape) not in [tuple(s) for s in shapes]:
        raise ValueError(f"{name}: expected {expected}; got shape {tuple(value.shape)}")
    if value.dtype != dtype:
        raise ValueError(f"{name}: expected {expected}; got dtype {value.dtype}")
    if value.device != torch.device(device):
        raise ValueError(f"{name}: expected {expected}; got device {value.device}")
    return value


class StreamOrder:
    """``with order:`` makes Warp work wait for pending torch work on entry and torch wait for the Warp work on exit
    (the current CUDA streams of both, which are one stream inside a capture; nothing to do on the CPU)."""

    def __init__(self, device: str):
        self.device = device
        self._warp_streams: dict[int, wp.Stream] = {}
        self._streams = None

    def _current(self) -> tuple[wp.Stream, wp.Stream] | None:
        torch_stream = torch.cuda.current_stream(self.device)
        if torch_stream.cuda_stream not in self._warp_streams:
            self._warp_streams[torch_stream.cuda_stream] = wp.stream_from_torch(torch_stream)
        as_warp, warp_stream = self._warp_streams[torch_stream.cuda_stream], wp.get_stream(self.device)
        return None if as_warp.cuda_stream == warp_stream.cuda_stream else (as_warp, warp_stream)

    def __enter__(self):
        if self.device != "cpu":
            self._streams = self._current()
            if self._streams:
                torch_stream, warp_stream = self._streams
                warp_stream.wait_stream(torch_stream)

    def __exit__(self, *exc):
        if self._streams:
            torch_stream, warp_stream = self._streams
            torch_stream.wait_stream(warp_stream)

    def capturing(self) -> bool:
        """Whether torch is capturing a CUDA graph on the device's current stream (the env's own captured graph is then
        not replayed but its kernels launched into the outer capture)."""
        return self.device != "cpu" and torch.cuda.is_current_stream_capturing()


class TorchGraph:
    """``graphed(work)``: ``work()`` (torch work, and Warp kernels launched in it) run op by op on a side stream the
    first time (which makes cuBLAS handles and lazily allocated state there), captured as one CUDA graph on that
    stream the second time, then replayed; returns what ``work`` returned when captured. Its inputs and outputs must
    be tensors that stay put. Warp is told the capture is torch's (Warp's ``ScopedCapture`` cannot hold torch work)."""

    def __init__(self, device: str):
        self.device = device
        self.stream = torch.cuda.Stream(device=device)
        self.graph: torch.cuda.CUDAGraph | None = None
        self.output = None
        self._warmed_up = False
        self._inputs = None

    def __call__(self, work: Callable[[], object]):
        if self.graph is None:
            self.stream.wait_stream(torch.cuda.current_stream(self.device))
            if not self._warmed_up:
                with torch.cuda.stream(self.stream):
                    output = work()
                torch.cuda.current_stream(self.device).wait_stream(self.stream)
                self._warmed_up = True
                return output
            graph = torch.cuda.CUDAGraph()
            with self._capture(graph):
                self.output = work()
            self.graph = graph
        self.graph.replay()
        return self.output

    def with_inputs(self, inputs, work: Callable[[object], object]):
        """``work(inputs)`` as ``__call__`` runs it, on a copy of ``inputs`` (a tensor or a TensorDict) in a buffer of
        the graph's own, into which each call copies them: a captured graph reads its inputs where it was captured."""
        if self._inputs is None:
            self._inputs = inputs.clone()
        self._inputs.copy_(inputs)
        return self(lambda: work(self._inputs))

    def release(self):
        """Free the captured graph (the next call captures it again). A graph holding NCCL collectives must be freed
        before the process group is destroyed, or destroying it hangs (pytorch/pytorch#115388)."""
        if self.graph is not None:
            torch.cuda.synchronize(self.device)
            self.graph.reset()
            self.graph = self.output = None

    @contextmanager
    def _capture(self, graph: torch.cuda.CUDAGraph) -> Iterator[None]:
        with (collection_paused(), wp.ScopedStream(wp.stream_from_torch(self.stream)),
              torch.cuda.graph(graph, stream=self.stream)):
            wp.capture_begin(force_module_load=False, external=True)
            try:
                yield
            finally:
                wp.capture_end()


class PhaseClock:
    """Seconds of consecutive phases of work on ``device`` without making the host wait: ``mark(i)`` between the
    phases records a CUDA event on a GPU (whose work runs after the host has queued it), the host clock on the CPU;
    ``seconds()`` waits for the last mark and returns each phase's seconds."""

    def __init__(self, device: str, phases: int):
        self.device = device
        self.cuda = torch.device(device).type == "cuda"
        self._marks: list[Any] = ([torch.cuda.Event(enable_timing=True) for _ in range(phases + 1)] if self.cuda
                                  else [0.0] * (phases + 1))

    def mark(self, i: int):
        if self.cuda:
            self._marks[i].record(torch.cuda.current_stream(self.device))
        else:
            self._marks[i] = time.perf_counter()

    def seconds(self) -> list[float]:
        if not self.cuda:
            return [b - a for a, b in zip(self._marks, self._marks[1:])]
        self._marks[-1].synchronize()
        return [a.elapsed_time(b) / 1e3 for a, b in zip(self._marks, self._marks[1:])]


__getattr__ = renamed(__name__, {"TorchOrder": "StreamOrder"})
"""The old name, until ``settings.deprecation.REMOVED_IN``."""
