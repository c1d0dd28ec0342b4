"""Camera observations (machinery, robot-agnostic): one view of Newton's ray-traced ``SensorCamera`` per env, rendered
on the env's device, and the stacks of the last ``frame_stack`` frames that the policy observes (``CameraConfig``).

Within an env step (all of it Warp work, captured with the step): after the physics, every view is rendered (the
frame an episode ends on, or the next frame); after the ended envs are reset, their bodies are placed (forward
kinematics) and only their views are rendered again; then each env's stack shifts by one frame, and an ended env's
stack is kept as its final observation and refilled with the new episode's first frame.
"""

from __future__ import annotations

import math
import os
from typing import Any

import numpy as np
import warp as wp

from .config import CameraConfig, ConfigError
from .kernels import END_DIVERGED, END_NONFINITE

SKIP_VIEW = wp.constant(-101)
"""``SensorCamera.WorldRenderFlag.DISABLE_PRESERVE``: the view is not rendered and keeps its pixels."""


def look_at(eye: tuple, target: tuple) -> np.ndarray:
    """The camera pose (position, xyzw quaternion) at ``eye`` whose -Z axis points at ``target`` and whose +Y is as
    close to world +Z as can be (Newton's camera frame: -Z forward, +Y up, +X right)."""
    eye, target = np.asarray(eye, dtype=np.float64), np.asarray(target, dtype=np.float64)
    forward = (target - eye) / np.linalg.norm(target - eye)
    right = np.cross(forward, (0.0, 0.0, 1.0))
    right /= np.linalg.norm(right)
    up = np.cross(right, forward)
    rotation = np.stack([right, up, -forward], axis=1)  # columns: the camera's axes in the world
    quat = np.asarray(wp.quat_from_matrix(wp.mat33f(*rotation.flatten())), dtype=np.float32)
    return np.hstack([eye.astype(np.float32), quat])


@wp.func
def channel(raw: wp.uint32, c: int) -> wp.uint8:
    """Colour channel c (0 red, 1 green, 2 blue) of a packed RGBA pixel."""
    return wp.uint8((raw >> wp.uint32(8 * c)) & wp.uint32(255))


@wp.func
def channel(raw: wp.float32, c: int) -> wp.float32:  # noqa: F811 (Warp overloads by argument type)
    """A depth pixel (m) as it is."""
    return raw


@wp.kernel
def mark_resets(terminated: wp.array(dtype=wp.bool), truncated: wp.array(dtype=wp.bool),
                reset: wp.array(dtype=wp.bool), views: wp.array(dtype=wp.int32)):
    """Per env: whether its episode ended (and was reset) this step, and its view index if so (else skipped)."""
    env = wp.tid()
    ended = terminated[env] or truncated[env]
    reset[env] = ended
    views[env] = wp.where(ended, env, SKIP_VIEW)


@wp.func
def refill(first: Any, env: int, y: int, x: int, channels: int, frames: int, stack: wp.array4d(dtype=Any)):
    """Every frame of one pixel of env ``env``'s stack set to the pixel ``first`` (a new episode's first frame)."""
    for f in range(frames):
        for c in range(channels):
            stack[env, f * channels + c, y, x] = channel(first, c)


@wp.kernel
def push_frame(frame: wp.array3d(dtype=Any), first_frame: wp.array3d(dtype=Any), reset: wp.array(dtype=wp.bool),
               end_reason: wp.array(dtype=wp.int32), channels: int, frames: int, stack: wp.array4d(dtype=Any),
               final_stack: wp.array4d(dtype=Any)):
    """One pixel of one env: the stack shifts by a frame and takes ``frame``; where the env was reset, that stack is
    its ``final_stack`` (the stack as it was where the physics broke down: the last sound observation) and the stack
    is refilled with ``first_frame``."""
    env, y, x = wp.tid()
    last = (frames - 1) * channels
    pixel = frame[env, y, x]
    if reset[env]:
        if end_reason[env] == END_NONFINITE or end_reason[env] == END_DIVERGED:
            for i in range(frames * channels):
                final_stack[env, i, y, x] = stack[env, i, y, x]
        else:
            for i in range(last):
                final_stack[env, i, y, x] = stack[env, i + channels, y, x]
            for c in range(channels):
                final_stack[env, last + c, y, x] = channel(pixel, c)
        refill(first_frame[env, y, x], env, y, x, channels, frames, stack)
    else:
        for i in range(last):
            stack[env, i, y, x] = stack[env, i + channels, y, x]
        for c in range(channels):
            stack[env, last + c, y, x] = channel(pixel, c)


@wp.kernel
def fill_stack(frame: wp.array3d(dtype=Any), mask: wp.array(dtype=wp.bool), channels: int, frames: int,
               stack: wp.array4d(dtype=Any)):
    """One pixel of one env: where ``mask``, every frame of the stack is ``frame`` (a new episode's first)."""
    env, y, x = wp.tid()
    if mask[env]:
        refill(frame[env, y, x], env, y, x, channels, frames, stack)


def image_dtype(cfg: CameraConfig):
    """The Warp dtype of an observation's pixels: uint8 colour or float32 metres."""
    return wp.uint8 if cfg.image == "rgb" else wp.float32


def bytes_per_env(cfg: CameraConfig) -> int:
    """Device memory the frames take per env: the observation stack, its final copy and the copy of that which each
    step hands out in ``info``, two rendered frames, the ray-tracer's per-view data (a few hundred bytes); the physics,
    the renderer's own buffers and torch's allocator add to it (docs/benchmarks.md has both measured)."""
    pixels = cfg.width_px * cfg.height_px
    stacks = 3 * pixels * cfg.channels * cfg.frame_stack * (1 if cfg.image == "rgb" else 4)
    return stacks + 2 * pixels * 4 + 512


def check_memory(cfg: CameraConfig, num_envs: int, device: str):
    """ConfigError with the estimate (``bytes_per_env``) where ``num_envs`` cameras would not fit in the device's free
    memory (the host's available memory on the CPU), before anything is allocated."""
    need = num_envs * bytes_per_env(cfg)
    if device == "cpu":
        free = os.sysconf("SC_AVPHYS_PAGES") * os.sysconf("SC_PAGE_SIZE")
    else:
        free = wp.get_device(device).free_memory
    if need > free:
        raise ConfigError(
            f"{num_envs:,} cameras of {cfg.width_px}x{cfg.height_px} {cfg.image} frames (frame_stack "
            f"{cfg.frame_stack}) need about {need / 1e9:,.1f} GB ({bytes_per_env(cfg) / 1e3:,.1f} kB per env); "
            f"{device} has {free / 1e9:,.1f} GB free: use fewer envs, smaller frames or fewer stacked frames")


class Camera:
    """The views of one scene's envs (a CPU shard's, or all of them): ``render`` after the physics, ``render_resets``
    after the resets, into persistent frames (graph-capturable)."""

    def __init__(self, scene, cfg: CameraConfig, device: str):
        from newton.sensors import SensorCamera

        assert SKIP_VIEW == SensorCamera.WorldRenderFlag.DISABLE_PRESERVE, "Newton's flag for a view left as it is"
        self.scene, self.cfg, n = scene, cfg, scene.num_envs
        if cfg.min_width_px > 0:
            distance_m = math.dist(cfg.eye_m, cfg.target_m)
            pixel_m = 2 * distance_m * math.tan(cfg.fov_rad / 2) / cfg.height_px
            thicken(scene.model, cfg.min_width_px * pixel_m)
        self.poses = wp.array(np.tile(look_at(cfg.eye_m, cfg.target_m), (n, 1)), dtype=wp.transformf, device=device)
        self.frame = wp.zeros((n, cfg.height_px, cfg.width_px), dtype=wp.uint32 if cfg.image == "rgb" else wp.float32,
                              device=device)
        """What each view saw after the physics (the frame an episode ended on, or the next one)."""
        self.sensor = SensorCamera(scene.model, load_textures=False)
        self.sensor.create_default_light(enable_shadows=False)
        self.rays = SensorCamera.compute_camera_rays_pinhole(cfg.width_px, cfg.height_px, camera_fov=cfg.fov_rad,
                                                             device=device)
        self.first_frame = wp.zeros_like(self.frame)
        """What the views of reset envs saw after their reset."""
        self.reset = wp.zeros(n, dtype=wp.bool, device=device)
        self.reset_views = wp.zeros(n, dtype=wp.int32, device=device)

    def _render(self, frame: wp.array, views: wp.array | None):
        self.scene.model.bvh_refit_shapes(self.scene.state_0)
        image = {"color_image" if self.cfg.image == "rgb" else "depth_image": frame}
        self.sensor.update(self.scene.state_0, self.poses, self.rays, world_indices=views, **image)

    def render(self):
        """Every view into ``frame``."""
        self._render(self.frame, None)

    def render_resets(self, terminated: wp.array, truncated: wp.array):
        """Place the bodies of the envs whose episode ended (``terminated | truncated``) and render their views into
        ``first_frame``."""
        wp.launch(mark_resets, dim=self.scene.num_envs, inputs=[terminated, truncated],
                  outputs=[self.reset, self.reset_views], device=self.frame.device)
        self.place_bodies(self.reset)
        self._render(self.first_frame, self.reset_views)

    def render_all_first(self, mask: wp.array):
        """Place the bodies where ``mask`` and render every view into ``first_frame`` (after ``reset`` or
        ``set_state``)."""
        self.place_bodies(mask)
        self._render(self.first_frame, None)

    def place_bodies(self, mask: wp.array):
        """The body poses of the envs in ``mask`` from their joint coordinates (the reset wrote the joints only)."""
        import newton

        s = self.scene
        newton.eval_fk(s.model, s.state_0.joint_q, s.state_0.joint_qd, s.state_0, mask=mask)


def thicken(model, min_width_m: float):
    """Draw box, capsule and cylinder shapes at least ``min_width_m`` thick (their scale; render only), the k-th shape
    of an env at least (1 + k/8) times that, so that no two thickened shapes are alike. With one width for all, two
    CUDA builds drew a few pixels of the same state differently (Newton's CUDA build orders an env's shapes by an
    atomic counter); with distinct widths none did (docs/benchmarks.md)."""
    import newton

    kinds, scales, world = model.shape_type.numpy(), model.shape_scale.numpy(), model.shape_world.numpy()
    order = np.argsort(world, kind="stable")
    rank = np.empty(len(world))
    rank[order] = np.arange(len(world)) - np.searchsorted(world[order], world[order])  # the shape's index in its env
    half = min_width_m / 2 * (1 + rank / 8)
    boxes = kinds == newton.GeoType.BOX
    scales[boxes] = np.maximum(scales[boxes], half[boxes, None])  # half extents
    round_ = (kinds == newton.GeoType.CAPSULE) | (kinds == newton.GeoType.CYLINDER)
    scales[round_, 0] = np.maximum(scales[round_, 0], half[round_])  # radius
    model.shape_scale.assign(scales)
