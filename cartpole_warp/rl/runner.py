"""The old module of the one-run training loop, now ``rl.loop.TrainingLoop`` (a run's books: ``rl.record.RunRecord``),
and of the policy functions, now in ``rl.policies``; until ``settings.deprecation.REMOVED_IN``."""

from __future__ import annotations

import importlib
import warnings

from ..settings.deprecation import REMOVED_IN, moved_names

_moved = moved_names(__name__, f"{__package__}.policies")


def __getattr__(name: str) -> object:
    """``TaskRunner`` and ``CartpoleRunner`` (the loop: ``rl.loop.TrainingLoop``) and the policy functions that lived
    here (``load_policy``, ``to_rsl_rl``, ...: now in ``rl.policies``)."""
    if name in ("TaskRunner", "CartpoleRunner"):
        warnings.warn(f"{__name__}.{name} is now {__package__}.loop.TrainingLoop, and a run's books (progress, save, "
                      f"load, policy, export) its records[0]; the old name goes in {REMOVED_IN}", DeprecationWarning,
                      stacklevel=2)
        return importlib.import_module(f"{__package__}.loop").TrainingLoop
    return _moved(name)
