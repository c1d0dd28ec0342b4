"""The evaluation layer: episode statistics and the solved rule that judges them (``statistics``), policy rollouts
(``rollouts``), the evaluation inside the training's step (``in_step``) and robustness grids (``robustness``)."""

from ..settings.deprecation import moved_names

__getattr__ = moved_names(__name__, f"{__name__}.rollouts")
"""``cartpole_warp.evaluation`` was the rollouts' module: its names, until ``settings.deprecation.REMOVED_IN``."""
