"""Newton's interactive ``ViewerGL`` on the batched env: the first envs stacked one above the other, seen side-on.

Needs a display and the ``viz`` extra (pyglet, imgui-bundle): ``pip install 'cartpole_warp[viz]'``.
"""

from __future__ import annotations

import math
import os
import sys
from collections.abc import Callable

import newton
import torch
import warp as wp

from ..engine.env import BatchedEnv
from . import ViewerUnavailable, prepare_viewers
from .frames import env_bounds

ROWS = 4
"""Envs shown: the first ones, one row each."""
MARGIN_M = 0.5
"""Space around each env's reach (m)."""


def check_viewer():
    """Raise ViewerUnavailable unless a display and pyglet (needed by Newton's OpenGL viewer) are present."""
    if sys.platform.startswith("linux") and not (os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY")):
        raise ViewerUnavailable("no display found ($DISPLAY is not set), so Newton's viewer cannot open; "
                                "run with --headless to write a GIF instead")
    try:
        import imgui_bundle  # noqa: F401
        import pyglet  # noqa: F401
    except ImportError as err:
        raise ViewerUnavailable(f"Newton's viewer needs the viz extra ({err.name} is missing): "
                                "pip install 'cartpole_warp[viz]'; or run with --headless") from None


def open_viewer(env: BatchedEnv):
    """A ``ViewerGL`` showing the first envs of ``env.scene``, side-on (looking along -X at the Y rails, Z up), one
    row each, spaced and framed by the robot's reach."""
    check_viewer()
    from newton.viewer import ViewerGL

    try:
        prepare_viewers()
        viewer = ViewerGL(width=1280, height=720)
    except Exception as err:  # GL context creation fails in many backend-specific ways
        raise ViewerUnavailable(f"cannot open Newton's viewer ({type(err).__name__}: {err}); "
                                "run with --headless instead") from None
    rows = min(ROWS, env.scene.num_envs)
    low, high = env_bounds(env)
    width_m, row_m = high - low + 2 * MARGIN_M
    viewer.set_model(env.scene.model)
    viewer.set_visible_worlds(range(rows))
    viewer.set_world_offsets((0.0, 0.0, row_m))
    tan_half_fov = math.tan(math.radians(viewer.camera.fov) / 2)
    distance_m = max(rows * row_m, width_m * 720 / 1280) / (2 * tan_half_fov)
    centre = (low + high) / 2
    viewer.set_camera(wp.vec3(distance_m, float(centre[0]), (rows - 1) * row_m / 2 + float(centre[1])), pitch=0.0,
                      yaw=180.0)
    return viewer


def view_interactively(env: BatchedEnv, policy: Callable[[torch.Tensor], torch.Tensor],
                       max_steps: int | None = None) -> int:
    """Run ``policy`` in Newton's viewer until its window closes (or ``max_steps`` env steps); return the steps run.
    ViewerUnavailable if the viewer cannot open."""
    viewer = open_viewer(env)
    model = env.scene.model
    shown = wp.array(model.articulation_world.numpy() < ROWS, dtype=wp.bool, device=model.device)
    obs, _ = env.reset()
    steps = 0
    try:
        with torch.inference_mode():
            while viewer.is_running() and (max_steps is None or steps < max_steps):
                if not viewer.is_paused():
                    obs = env.step(policy(obs).to(torch.float32))[0]
                    steps += 1
                state = env.scene.state_0
                newton.eval_fk(model, state.joint_q, state.joint_qd, state, mask=shown)  # poses of fresh resets too
                viewer.begin_frame(steps * env.env_dt)
                viewer.log_state(state)
                viewer.end_frame()
    finally:
        viewer.close()
    return steps
