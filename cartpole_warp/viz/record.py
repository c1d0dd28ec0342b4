"""Recording env 0 of a rollout: a GIF side view and a time-sampled USD stage (Newton's ``ViewerUSD``).

    recorder = Recorder(env.scene, env.env_dt, out_dir / "cartpole.gif", out_dir / "cartpole.usda")
    rollout(env, policy, steps, on_step=recorder)
    recorder.close()                      # writes both files; usdview out_dir/cartpole.usda plays the stage
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
from newton.viewer import ViewerUSD

from ..scene import Scene
from .frames import Geometry, write_gif


class Recorder:
    """Called once per env step (``recorder(step)``), it records the bodies of env 0 of ``scene``."""

    def __init__(self, scene: Scene, env_dt: float, gif_path: Path, usd_path: Path):
        self.scene, self.env_dt = scene, env_dt
        self.gif_path, self.usd_path = Path(gif_path), Path(usd_path)
        self.geometry = Geometry(scene.model)
        self.frames: list[np.ndarray] = []
        self.fps = max(1, round(1.0 / env_dt))
        """Time codes per second of the USD stage: one time code per env step."""
        self.usd_path.parent.mkdir(parents=True, exist_ok=True)
        self._usd_tmp = self.usd_path.with_name(f".{self.usd_path.name}.tmp.usda")
        self.usd = ViewerUSD(str(self._usd_tmp), fps=self.fps, num_frames=None)
        self.usd.set_model(scene.model)
        self.usd.set_visible_worlds([0])

    def __call__(self, step: int):
        state = self.scene.state_0
        self.frames.append(self.geometry.body_transforms(state))
        self.usd.begin_frame(step / self.fps)
        self.usd.log_state(state)
        self.usd.end_frame()

    def close(self) -> tuple[Path, Path]:
        """Write the GIF and the USD stage; return their paths."""
        self.usd.close()
        os.replace(self._usd_tmp, self.usd_path)
        write_gif(self.gif_path, self.geometry, np.stack(self.frames), self.env_dt)
        return self.gif_path, self.usd_path
