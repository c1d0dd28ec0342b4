"""Write the package's stages (``cartpole_warp.engine.stages``: their physical facts and how they are authored) next
to this script: ``cartpole.usda``, ``cartpole_dmc.usda``, ``cartpole_dmc_<n>poles.usda`` for n = 2, 3 and the
multi-arm pendulum's ``multiarm_pendulum.usda``, ``multiarm_pendulum_<n>arms.usda`` for n = 2, 3.

Run: ``python usd/make_cartpole.py`` writes them all; ``python usd/make_cartpole.py out.usda [out_dmc.usda]`` writes
the classic stage (and the dm_control one) elsewhere.
"""

import sys
from pathlib import Path

from cartpole_warp.engine.stages import CHAINS, MULTIARM_STAGES, dmc_stage_text, multiarm_stage_text, stage_text


def main():
    here = Path(__file__).parent
    outs = [Path(arg) for arg in sys.argv[1:3]] or [
        here / "cartpole.usda", here / "cartpole_dmc.usda", *(here / f"cartpole_dmc_{n}poles.usda" for n in CHAINS),
        *(here / name for name in MULTIARM_STAGES.values())]
    texts = (stage_text(), dmc_stage_text(), *(dmc_stage_text(n) for n in CHAINS),
             *(multiarm_stage_text(n) for n in MULTIARM_STAGES))
    for out, text in zip(outs, texts):
        out.write_text(text)
        print(f"wrote {out}")


if __name__ == "__main__":
    main()
