"""Pictures of the env: GIF side views (``frames``), recordings of a rollout as GIF and time-sampled USD
(``record``, Newton's ``ViewerUSD``) and Newton's interactive ``ViewerGL`` (``viewer``)."""

from ..engine.runtime import compile_without_adjoints

NEWTON_VIEWER_MODULES = ("newton._src.viewer.kernels", "newton._src.geometry.raycast", "newton._src.sim.articulation")
"""The Warp modules that Newton's viewers load (Newton 1.8): compiled here without adjoints (``prepare_viewers``)."""


class ViewerUnavailable(RuntimeError):
    """A viewer cannot open here; the message says why and what to do instead."""


def prepare_viewers() -> None:
    """Before a Newton viewer is made: its modules compile without adjoint code, which nothing here uses and which
    makes a first recording's compile longer (docs/benchmarks.md)."""
    compile_without_adjoints(*NEWTON_VIEWER_MODULES)
