"""System identification: fit a task's physical parameters to a recorded trajectory by gradient descent through the
simulator (``gradients.rollout``).

    python -m cartpole_warp.tools.sysid --task cartpole-swingup --trajectory rig.csv
    python -m cartpole_warp.tools.sysid --task cartpole-balance --trajectory RUN/play/trajectory.npz
    python -m cartpole_warp.tools.sysid --task cartpole-swingup --config multiarm_pendulum --trajectory y_id.npz \
        --validate y_vad.npz --fit pole_inertia_scale pole_damping_n_m_s_rad pole_friction_n_m --window-steps 100 500

The recording and the method (``identification.sysid``):
"""

from __future__ import annotations

import sys

from ..cli import clean_errors, parse, quiet_libraries
from ..engine.scene import StageError
from ..identification import sysid
from ..settings.config import ConfigError
from ..settings.deprecation import moved_names


def main(argv: list[str] | None = None) -> int:
    quiet_libraries()
    with clean_errors(ConfigError, StageError):
        method = (sysid.__doc__ or "").partition("\n\n")[2]  # the library's docstring after its first paragraph
        args = parse(sysid.SysidArgs, sysid.SysidArgs(), sys.argv[1:] if argv is None else argv, f"{__doc__}\n{method}",
                     aliases={"--from": "--start-from"})
        sysid.fit(args)
    return 0


__getattr__ = moved_names(__name__, "cartpole_warp.identification.sysid")
"""The library's names that lived here (``fit``, ``SysidArgs``, ...), until ``settings.deprecation.REMOVED_IN``."""


if __name__ == "__main__":
    sys.exit(main())
