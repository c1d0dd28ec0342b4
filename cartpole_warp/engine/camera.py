"""Camera observations (machinery, robot-agnostic): one view of Newton's ray-traced ``SensorCamera`` per env, rendered
on the env's device, and the stacks of the last ``frame_stack`` frames that the policy observes (``CameraConfig``).

Within an env step (all of it Warp work, captured with the step): after the physics, every view is rendered (the
frame an episode ends on, or the next frame); after the ended envs are reset, their bodies are placed (forward
kinematics) and only their views are rendered again, listed into passes of a few views each (a pass per
``views_per_pass`` ended envs, a loop that runs on the device: ``wp.capture_while``); then each env's stack shifts by
one frame, and an ended env's stack is kept as its final observation and refilled with the new episode's first frame.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
import warp as wp

from ..settings.config import CameraConfig, ConfigError
from .kernels import END_DIVERGED, END_NONFINITE
from .runtime import free_memory_bytes

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
def sample(frame: wp.array2d(dtype=wp.uint32), env: int, u: int, c: int,
           stack: wp.array3d(dtype=wp.uint8)) -> wp.uint8:
    """Unit u of a colour stack of bytes: channel c of pixel u."""
    return channel(frame[env, u], c)


@wp.func
def sample(frame: wp.array2d(dtype=wp.uint32), env: int, u: int, c: int,  # noqa: F811 (Warp overloads by type)
           stack: wp.array3d(dtype=wp.uint32)) -> wp.uint32:
    """Unit u of a colour stack moved a word at a time: channel c of pixels 4u to 4u + 3, a byte each (the first
    pixel's the lowest)."""
    p = 4 * u
    return (wp.uint32(channel(frame[env, p], c)) | (wp.uint32(channel(frame[env, p + 1], c)) << wp.uint32(8))
            | (wp.uint32(channel(frame[env, p + 2], c)) << wp.uint32(16))
            | (wp.uint32(channel(frame[env, p + 3], c)) << wp.uint32(24)))


@wp.func
def sample(frame: wp.array2d(dtype=wp.float32), env: int, u: int, c: int,  # noqa: F811 (Warp overloads by type)
           stack: wp.array3d(dtype=wp.float32)) -> wp.float32:
    """Unit u of a depth stack: pixel u (m)."""
    return frame[env, u]


@wp.func
def refill(first_frame: wp.array2d(dtype=Any), env: int, u: int, channels: int, frames: int,
           stack: wp.array3d(dtype=Any)):
    """Every frame of unit u of env ``env``'s stack set to that unit of ``first_frame`` (a new episode's first)."""
    for c in range(channels):
        first = sample(first_frame, env, u, c, stack)
        for f in range(frames):
            stack[env, f * channels + c, u] = first


@wp.kernel
def list_resets(terminated: wp.array(dtype=wp.bool), truncated: wp.array(dtype=wp.bool),
                reset: wp.array(dtype=wp.bool), listed: wp.array(dtype=wp.int32), ended_envs: wp.array(dtype=wp.int32)):
    """Per env: whether its episode ended (and was reset) this step; the ended envs listed in ``ended_envs`` (in no
    particular order: each view draws its own env whichever pass it is in), ``listed`` counting them."""
    env = wp.tid()
    ended = terminated[env] or truncated[env]
    reset[env] = ended
    if ended:
        ended_envs[wp.atomic_add(listed, 0, 1)] = env


@wp.kernel
def first_pass(listed: wp.array(dtype=wp.int32), next_listed: wp.array(dtype=wp.int32),
               more: wp.array(dtype=wp.int32)):
    """Start the passes at the first listed env; ``more`` (the loop's condition): whether any env was listed."""
    next_listed[0] = 0
    more[0] = wp.where(listed[0] > 0, 1, 0)


@wp.kernel
def pass_views(ended_envs: wp.array(dtype=wp.int32), listed: wp.array(dtype=wp.int32),
               next_listed: wp.array(dtype=wp.int32), views: wp.array(dtype=wp.int32)):
    """View i of this pass draws the (next_listed + i)-th listed env, or is skipped past the end of the list."""
    i = wp.tid()
    k = next_listed[0] + i
    views[i] = wp.where(k < listed[0], ended_envs[wp.min(k, ended_envs.shape[0] - 1)], SKIP_VIEW)


@wp.kernel
def scatter_views(pass_frames: wp.array3d(dtype=Any), views: wp.array(dtype=wp.int32),
                  first_frame: wp.array3d(dtype=Any)):
    """One pixel of a pass's view i, copied to its env's frame."""
    i, y, x = wp.tid()
    env = views[i]
    if env != SKIP_VIEW:
        first_frame[env, y, x] = pass_frames[i, y, x]


@wp.kernel
def next_pass(listed: wp.array(dtype=wp.int32), views_per_pass: int, next_listed: wp.array(dtype=wp.int32),
              more: wp.array(dtype=wp.int32)):
    """Move on by a pass; ``more``: whether listed envs are left."""
    next_listed[0] = next_listed[0] + views_per_pass
    more[0] = wp.where(next_listed[0] < listed[0], 1, 0)


@wp.kernel
def push_frame(frame: wp.array2d(dtype=Any), first_frame: wp.array2d(dtype=Any), reset: wp.array(dtype=wp.bool),
               end_reason: wp.array(dtype=wp.int32), channels: int, frames: int, stack: wp.array3d(dtype=Any),
               final_stack: wp.array3d(dtype=Any)):
    """One unit (``sample``: a pixel, or a word of four colour pixels) of one env: the stack shifts by a frame and
    takes ``frame``; where the env was reset, that stack is its ``final_stack`` (the stack as it was where the physics
    broke down: the last sound observation) and the stack is refilled with ``first_frame``."""
    env, u = wp.tid()
    last = (frames - 1) * channels
    if reset[env]:
        if end_reason[env] == END_NONFINITE or end_reason[env] == END_DIVERGED:
            for i in range(frames * channels):
                final_stack[env, i, u] = stack[env, i, u]
        else:
            for i in range(last):
                final_stack[env, i, u] = stack[env, i + channels, u]
            for c in range(channels):
                final_stack[env, last + c, u] = sample(frame, env, u, c, stack)
        refill(first_frame, env, u, channels, frames, stack)
    else:
        for i in range(last):
            stack[env, i, u] = stack[env, i + channels, u]
        for c in range(channels):
            stack[env, last + c, u] = sample(frame, env, u, c, stack)


@wp.kernel
def fill_stack(frame: wp.array2d(dtype=Any), mask: wp.array(dtype=wp.bool), channels: int, frames: int,
               stack: wp.array3d(dtype=Any)):
    """One unit of one env: where ``mask``, every frame of the stack is ``frame`` (a new episode's first)."""
    env, u = wp.tid()
    if mask[env]:
        refill(frame, env, u, channels, frames, stack)


def image_dtype(cfg: CameraConfig):
    """The Warp dtype of an observation's pixels: uint8 colour or float32 metres."""
    return wp.uint8 if cfg.image == "rgb" else wp.float32


def bytes_per_env(cfg: CameraConfig) -> int:
    """Device memory the frames take per env: the observation stack, its final copy and the copy of that which each
    step hands out in ``info``, the rendered frames (after the physics, after the resets, and the passes' frames: at
    most one more), the ray-tracer's per-view data (a few hundred bytes); the physics, the renderer's own buffers and
    torch's allocator add to it (docs/benchmarks.md has both measured)."""
    pixels = cfg.width_px * cfg.height_px
    stacks = 3 * pixels * cfg.channels * cfg.frame_stack * (1 if cfg.image == "rgb" else 4)
    return stacks + 3 * pixels * 4 + 512


def check_memory(cfg: CameraConfig, num_envs: int, device: str):
    """ConfigError with the estimate (``bytes_per_env``) where ``num_envs`` cameras would not fit in the device's free
    memory (the host's available memory on the CPU), before anything is allocated."""
    need = num_envs * bytes_per_env(cfg)
    free = free_memory_bytes(device)
    if need > free:
        raise ConfigError(
            f"{num_envs:,} cameras of {cfg.width_px}x{cfg.height_px} {cfg.image} frames (frame_stack "
            f"{cfg.frame_stack}) need about {need / 1e9:,.1f} GB ({bytes_per_env(cfg) / 1e3:,.1f} kB per env); "
            f"{device} has {free / 1e9:,.1f} GB free: use fewer envs, smaller frames or fewer stacked frames")


PASSES_PER_RENDER = 16
"""On CUDA the views of the envs that reset are drawn in passes of ``num_envs / PASSES_PER_RENDER`` views: a view
that is skipped still costs part of a drawn one, so drawing only the listed views in small passes beats one pass over
every view when few envs reset (the measurement: docs/benchmarks.md, "Where a colour step went")."""


class Camera:
    """The views of one scene's envs (a CPU shard's, or all of them): ``render`` after the physics, ``render_resets``
    after the resets, into persistent frames (graph-capturable). ``views_per_pass``: views drawn at once for the
    envs that reset (default: a sixteenth of the envs on CUDA; every env, one pass without a loop, on the CPU, where
    a skipped view costs nothing, and where the CUDA driver has no conditional graph nodes, before CUDA 12.4)."""

    def __init__(self, scene, cfg: CameraConfig, device: str, views_per_pass: int | None = None):
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
        """What each view saw after the physics (the frame an episode ends on, or the next one)."""
        self.sensor = SensorCamera(scene.model, load_textures=False)
        self.sensor.create_default_light(enable_shadows=False)
        self.rays = SensorCamera.compute_camera_rays_pinhole(cfg.width_px, cfg.height_px, camera_fov=cfg.fov_rad,
                                                             device=device)
        self.first_frame = wp.zeros_like(self.frame)
        """What the views of reset envs saw after their reset."""
        self.reset = wp.zeros(n, dtype=wp.bool, device=device)
        if views_per_pass is None:
            loop = device != "cpu" and wp.is_conditional_graph_supported()
            views_per_pass = -(-n // PASSES_PER_RENDER) if loop else n
        self.views_per_pass = min(max(views_per_pass, 1), n)
        self._ended_envs = wp.zeros(n, dtype=wp.int32, device=device)
        self._listed, self._next_listed, self._more = (wp.zeros(1, dtype=wp.int32, device=device) for _ in range(3))
        self._pass_views = wp.zeros(self.views_per_pass, dtype=wp.int32, device=device)
        self._pass_poses = self.poses[: self.views_per_pass]
        self._pass_frames = wp.zeros((self.views_per_pass, *self.frame.shape[1:]), dtype=self.frame.dtype,
                                     device=device)

    def _render(self, frame: wp.array, poses: wp.array, views: wp.array | None):
        image = {"color_image" if self.cfg.image == "rgb" else "depth_image": frame}
        self.sensor.update(self.scene.state_0, poses, self.rays, world_indices=views, **image)

    def render(self):
        """Every view into ``frame``."""
        self.scene.model.bvh_refit_shapes(self.scene.state_0)
        self._render(self.frame, self.poses, None)

    def render_resets(self, terminated: wp.array, truncated: wp.array):
        """Place the bodies of the envs whose episode ended (``terminated | truncated``) and render their views into
        ``first_frame``, ``views_per_pass`` at a time (in a loop on the device where that is fewer than all)."""
        device = self.frame.device
        self._listed.zero_()
        wp.launch(list_resets, dim=self.scene.num_envs, inputs=[terminated, truncated],
                  outputs=[self.reset, self._listed, self._ended_envs], device=device)
        wp.launch(first_pass, dim=1, inputs=[self._listed], outputs=[self._next_listed, self._more], device=device)
        self.place_bodies(self.reset)
        self.scene.model.bvh_refit_shapes(self.scene.state_0)
        if self.views_per_pass < self.scene.num_envs:
            wp.capture_while(self._more, self._render_pass)
        else:
            self._render_pass()

    def _render_pass(self):
        device = self.frame.device
        wp.launch(pass_views, dim=self.views_per_pass, inputs=[self._ended_envs, self._listed, self._next_listed],
                  outputs=[self._pass_views], device=device)
        self._render(self._pass_frames, self._pass_poses, self._pass_views)
        wp.launch(scatter_views, dim=self._pass_frames.shape, inputs=[self._pass_frames, self._pass_views],
                  outputs=[self.first_frame], device=device)
        wp.launch(next_pass, dim=1, inputs=[self._listed, self.views_per_pass],
                  outputs=[self._next_listed, self._more], device=device)

    def _units(self, *arrays: wp.array) -> tuple[wp.array, ...]:
        """The stack kernels' layout of ``arrays``: frames (N, H, W) as (N, pixels), stacks (N, planes, H, W) as (N,
        planes, units), a unit a pixel, or for colour stacks whose pixel count divides by 4 a 32-bit word of four
        pixels (a word a thread moves four pixels per memory access where a byte a thread moves one;
        docs/benchmarks.md has the measurement)."""
        out = []
        for a in arrays:
            if a.ndim == 3:
                out.append(a.reshape((a.shape[0], a.shape[1] * a.shape[2])))
            elif a.dtype == wp.uint8 and a.shape[2] * a.shape[3] % 4 == 0:
                out.append(wp.array(ptr=a.ptr, dtype=wp.uint32, shape=(*a.shape[:2], a.shape[2] * a.shape[3] // 4),
                                    device=a.device))
            else:
                out.append(a.reshape((*a.shape[:2], a.shape[2] * a.shape[3])))
        return tuple(out)

    def push(self, end_reason: wp.array, stack: wp.array, final_stack: wp.array):
        """Shift each env's ``stack`` (N, channels x frame_stack, H, W) by the frame rendered after the physics; where
        the env was reset, keep it as ``final_stack`` and refill it with the new episode's first frame."""
        frame, first_frame, stack, final_stack = self._units(self.frame, self.first_frame, stack, final_stack)
        wp.launch(push_frame, dim=(stack.shape[0], stack.shape[2]),
                  inputs=[frame, first_frame, self.reset, end_reason, self.cfg.channels, self.cfg.frame_stack],
                  outputs=[stack, final_stack], device=self.frame.device)

    def start_stacks(self, mask: wp.array, stack: wp.array):
        """Place the bodies where ``mask`` (after ``reset`` or ``set_state``), render every view into ``first_frame``
        and fill every frame of those envs' ``stack`` with it."""
        self.place_bodies(mask)
        self.scene.model.bvh_refit_shapes(self.scene.state_0)
        self._render(self.first_frame, self.poses, None)
        first_frame, stack = self._units(self.first_frame, stack)
        wp.launch(fill_stack, dim=(stack.shape[0], stack.shape[2]),
                  inputs=[first_frame, mask, self.cfg.channels, self.cfg.frame_stack], outputs=[stack],
                  device=self.frame.device)

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


class CameraObservations:
    """The policy observes each env's last ``frame_stack`` frames (an observation source, as
    ``observations.StateObservations``): one ``Camera`` per shard, the stacks and their final copies."""

    images = True

    def __init__(self, cfg: CameraConfig, num_envs: int, device: str):
        check_memory(cfg, num_envs, device)
        self.cfg, self.device = cfg, device
        self.modules = [wp.get_module(__name__)]
        """The Warp modules of its kernels (loaded with the env's)."""
        self.cameras: list[Camera] = []
        """Each shard's views (``attach``)."""

    def attach(self, shards: list) -> None:
        """A camera on each shard's scene."""
        self.cameras = [Camera(shard.scene, self.cfg, self.device) for shard in shards]

    def buffers(self, state_obs: wp.array, final_state_obs: wp.array) -> tuple[wp.array, wp.array]:
        """(the observations, the final observations of ended episodes): the frame stacks (N, channels x frame_stack,
        H, W), allocated here; the task's state stays the critic's."""
        n, cfg = state_obs.shape[0], self.cfg
        shape = (n, cfg.channels * cfg.frame_stack, cfg.height_px, cfg.width_px)
        self.stacks = wp.zeros(shape, dtype=image_dtype(cfg), device=self.device)
        self.final_stacks = wp.zeros(shape, dtype=image_dtype(cfg), device=self.device)
        return self.stacks, self.final_stacks

    def after_physics(self, shard) -> None:
        """Render the shard's views (the frame an episode ends on, or the next one)."""
        self.cameras[shard.index].render()

    def after_step(self, shard, results) -> None:
        """Render the views of the envs that reset, then push each stack's newest frame (``Camera.push``)."""
        view = self.cameras[shard.index]
        view.render_resets(results.terminated, results.truncated)
        view.push(results.end_reason, shard.rows(self.stacks), shard.rows(self.final_stacks))

    def start(self, shard, mask: wp.array) -> None:
        """Where ``mask`` (new episodes): every frame of the stack is the episode's first."""
        self.cameras[shard.index].start_stacks(shard.rows(mask), shard.rows(self.stacks))

    def space(self, shape: tuple[int, ...]):
        """One env's observation space: uint8 colour in [0, 255], or float32 metres (0: nothing hit)."""
        import gymnasium

        if self.cfg.image == "rgb":
            return gymnasium.spaces.Box(0, 255, shape, np.uint8)
        return gymnasium.spaces.Box(0.0, np.inf, shape, np.float32)
