"""tensordict (which rsl-rl is built on) imported without ``torch._dynamo``: at import time tensordict marks a few
functions for ``torch.compile`` (``torch.compiler.allow_in_graph``, ``assume_constant_result``), and each mark
imports Dynamo (seconds of start-up; docs/benchmarks.md) although nothing here compiles. While tensordict
imports, those two are swapped for functions that only remember the marks (set and restored: nothing else in the
process sees the swap); ``mark_for_compile`` hands them to Dynamo before a ``torch.compile``
(``agent.torch_compile_mode``), as tensordict would have. Import this module before rsl-rl or tensordict."""

from __future__ import annotations

import sys
from collections.abc import Callable

import torch.compiler

MARKERS = ("allow_in_graph", "assume_constant_result")
"""The ``torch.compiler`` functions that tensordict calls at import time."""

_waiting: list[tuple[str, Callable]] = []
"""Marks not yet given to Dynamo: (marker, function)."""


def _deferred(marker: str, original: Callable) -> Callable:
    def mark(fn):
        """The ``original`` marker where Dynamo is loaded already, else later (``mark_for_compile``); returns ``fn``,
        as it does."""
        if "torch._dynamo" in sys.modules:
            return original(fn)
        _waiting.extend((marker, f) for f in (fn if isinstance(fn, (list, tuple)) else [fn]))
        return fn

    return mark


def mark_for_compile() -> None:
    """Give Dynamo the marks tensordict made while it was imported (before ``torch.compile``)."""
    while _waiting:
        marker, fn = _waiting.pop(0)
        getattr(torch.compiler, marker)(fn)


if "tensordict" not in sys.modules:
    _markers = {name: getattr(torch.compiler, name) for name in MARKERS}
    for _name, _marker in _markers.items():
        setattr(torch.compiler, _name, _deferred(_name, _marker))
    try:
        import tensordict  # noqa: F401
    finally:
        for _name, _marker in _markers.items():
            setattr(torch.compiler, _name, _marker)
