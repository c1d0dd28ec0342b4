"""Side views of single envs drawn with Pillow (no GL, no display): GIF frames, video frames and the ``rgb_array``
frames of the gymnasium and SB3 wrappers, all from one renderer.

Geometry comes from the Newton model (box and capsule shapes, their body, size, offset and colour; the model's up axis
is up, the widest shape's long axis runs to the right), motion from body transforms (``Geometry.body_transforms``), so
nothing here knows a robot's dimensions.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import NamedTuple

import newton
import numpy as np
import warp as wp
from PIL import Image, ImageDraw, ImageFont

from ..engine.env import BatchedEnv
from ..engine.runtime import warp_output
from ..settings.files import atomic_write

BACKGROUND = (250, 250, 250)
INK = (40, 40, 40)


def _quat_rotate(q: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Rotate vectors ``v`` (..., 3) by quaternions ``q`` (..., 4) stored (x, y, z, w)."""
    xyz, w = q[..., :3], q[..., 3:4]
    t = 2.0 * np.cross(xyz, v)
    return v + w * t + np.cross(xyz, t)


BOX_CORNERS = np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)], dtype=np.float64)
_golden = np.pi * (3.0 - np.sqrt(5.0))
_heights = np.linspace(-1.0, 1.0, 48)
SPHERE_POINTS = np.stack([np.sqrt(1 - _heights**2) * np.cos(_golden * np.arange(48)),
                          np.sqrt(1 - _heights**2) * np.sin(_golden * np.arange(48)), _heights], axis=1)
"""Unit-sphere points (Fibonacci lattice) whose projections outline a capsule's rounded ends."""


def outline_points(kind: int, scale: np.ndarray) -> np.ndarray | None:
    """Points (k, 3) in the shape's frame whose convex hull is the shape: a box's corners, or a capsule's end spheres
    (Newton's capsule: scale = (radius, half height, 0) along local Z); None for other shapes."""
    if kind == newton.GeoType.BOX:
        return BOX_CORNERS * scale
    if kind == newton.GeoType.CAPSULE:
        radius, half_height = scale[0], scale[1]
        return np.concatenate([SPHERE_POINTS * radius + (0.0, 0.0, end) for end in (-half_height, half_height)])
    return None


@dataclass
class Shape:
    """One drawn shape (box or capsule) of the recorded env."""

    name: str
    body: int
    """Index into the recorded bodies, -1 for a static shape."""
    points_m: np.ndarray
    """(k, 3) points in the shape's frame whose convex hull is the shape."""
    local_transform: np.ndarray
    """(7,) position (m) and (x, y, z, w) quaternion relative to the body (to the world if static)."""
    color_srgb: tuple[float, float, float]


class Geometry:
    """The shapes and bodies of one env (world) of a Newton model, and their poses over time."""

    def __init__(self, model: newton.Model, world: int = 0):
        self.model = model
        body_world = model.body_world.numpy()
        self.body_ids = np.flatnonzero(body_world == world)
        self.body_names = [model.body_label[i].rsplit("/", 1)[-1] for i in self.body_ids]
        shape_world, shape_body = model.shape_world.numpy(), model.shape_body.numpy()
        kinds, scales = model.shape_type.numpy(), model.shape_scale.numpy()
        transforms, colors = model.shape_transform.numpy(), model.shape_color.numpy()
        body_index = {int(b): i for i, b in enumerate(self.body_ids)}
        self.shapes = []
        for s in np.flatnonzero(shape_world == world):
            points = outline_points(kinds[s], scales[s].astype(np.float64))
            if points is None:
                continue
            parts = model.shape_label[s].strip("/").split("/")
            body = body_index.get(int(shape_body[s]), -1)
            name = self.body_names[body] if body >= 0 else parts[-2] if len(parts) > 1 else parts[-1]
            self.shapes.append(Shape(name=name, body=body, points_m=points,
                                  local_transform=transforms[s].astype(np.float64),
                                  color_srgb=tuple(float(c) for c in colors[s])))
        self._fk_mask = wp.array(model.articulation_world.numpy() == world, dtype=wp.bool, device=model.device)
        up = int(model.up_axis)
        widest = max(self.shapes, key=lambda shape: np.ptp(shape.points_m, axis=0).max(), default=None)
        across = [axis for axis in (0, 1, 2) if axis != up]
        if widest is not None:
            extent = np.ptp(_quat_rotate(widest.local_transform[3:], widest.points_m), axis=0)
            across.sort(key=lambda axis: -extent[axis])
        self.view_axes = (across[0], up)
        """World axes drawn to the right (the widest shape's long axis, e.g. the rail) and upwards (the model's up
        axis)."""

    def body_transforms(self, state: newton.State) -> np.ndarray:
        """(bodies, 7) world transforms of the env's bodies, from the state's joint coordinates."""
        newton.eval_fk(self.model, state.joint_q, state.joint_qd, state, mask=self._fk_mask)
        return state.body_q.numpy()[self.body_ids].astype(np.float64)

    def outlines(self, transforms: np.ndarray) -> list[tuple[Shape, np.ndarray]]:
        """Each shape with its outline points (k, 2) in view coordinates (right, up; m) for body ``transforms``."""
        return [(shape, self.shape_points(shape, transforms[shape.body] if shape.body >= 0 else None)
                 [:, self.view_axes]) for shape in self.shapes]

    def shape_points(self, shape: Shape, body_transform: np.ndarray | None) -> np.ndarray:
        """(k, 3) world outline points of a shape given its body's transform (None for a static shape)."""
        local, count = shape.local_transform, len(shape.points_m)
        points = _quat_rotate(np.broadcast_to(local[3:], (count, 4)), shape.points_m) + local[:3]
        if body_transform is not None:
            points = _quat_rotate(np.broadcast_to(body_transform[3:], (count, 4)), points) + body_transform[:3]
        return points


def _convex_hull(points: np.ndarray) -> list[tuple[float, float]]:
    """Convex hull of 2-D points, counter-clockwise (Andrew's monotone chain)."""
    pts = sorted(set(map(tuple, np.round(points, 9))))
    if len(pts) <= 2:
        return pts

    def half(seq):
        hull = []
        for p in seq:
            while len(hull) >= 2 and ((hull[-1][0] - hull[-2][0]) * (p[1] - hull[-2][1])
                                      - (hull[-1][1] - hull[-2][1]) * (p[0] - hull[-2][0])) <= 0:
                hull.pop()
            hull.append(p)
        return hull

    lower, upper = half(pts), half(reversed(pts))
    return lower[:-1] + upper[:-1]


def view_bounds(geometry: Geometry, frames: Sequence[np.ndarray], reach: bool = False) -> tuple[np.ndarray, np.ndarray]:
    """(low, high) view coordinates (right, up; m) holding the shapes in every one of ``frames`` (body transforms);
    ``reach`` also holds the moving shapes turned upside down about the static shapes' centre: everywhere a live
    robot can swing (a taller robot gets a taller box)."""
    corners = np.concatenate([c for transforms in frames for _, c in geometry.outlines(transforms)])
    low, high = corners.min(axis=0), corners.max(axis=0)
    if reach:
        moving = np.concatenate([c for transforms in frames for shape, c in geometry.outlines(transforms)
                                 if shape.body >= 0])
        static = [c for shape, c in geometry.outlines(frames[0]) if shape.body < 0]
        center = np.concatenate(static).mean(axis=0)[1] if static else moving[:, 1].mean()
        span = np.abs(moving[:, 1] - center).max()
        low[1], high[1] = min(low[1], center - span), max(high[1], center + span)
    return low, high


def env_bounds(env: BatchedEnv) -> tuple[np.ndarray, np.ndarray]:
    """``view_bounds`` of env 0 as it is now, with its reach: the space one env needs in a live view."""
    geometry = Geometry(env.scene.model, world=0)
    return view_bounds(geometry, [geometry.body_transforms(env.scene.state_0)], reach=True)


class SideView:
    """Draws the shapes of one env inside fixed bounds (view coordinates, m) at ``width_px``; the height follows the
    bounds' aspect, both rounded to even pixels (video encoders need them)."""

    def __init__(self, geometry: Geometry, low: np.ndarray, high: np.ndarray, width_px: int = 640):
        self.geometry, self.low = geometry, low
        self.scale = width_px / (high[0] - low[0])
        self.size = (width_px // 2 * 2, int(math.ceil((high[1] - low[1]) * self.scale / 2)) * 2)
        self.font = ImageFont.load_default(size=14)

    @classmethod
    def around(cls, geometry: Geometry, frames: Sequence[np.ndarray], width_px: int = 640,
               reach: bool = False) -> SideView:
        """Bounds holding the shapes in every one of ``frames`` (body transforms), with a 5% margin; ``reach`` also
        holds the moving shapes turned upside down (for live frames, whose future poses are unknown)."""
        low, high = view_bounds(geometry, frames, reach)
        margin = 0.05 * (high - low).max()
        return cls(geometry, low - margin, high + margin, width_px)

    def image(self, transforms: np.ndarray, caption: str | None = None) -> Image.Image:
        """The env drawn for body ``transforms`` (bodies, 7)."""
        width, height = self.size
        image = Image.new("RGB", self.size, BACKGROUND)
        draw = ImageDraw.Draw(image)
        for shape, corners in self.geometry.outlines(transforms):
            points = [((x - self.low[0]) * self.scale, height - (z - self.low[1]) * self.scale)
                      for x, z in _convex_hull(corners)]
            draw.polygon(points, fill=tuple(int(255 * c) for c in shape.color_srgb), outline=INK)
        if caption:
            draw.text((8, 4), caption, fill=INK, font=self.font)
        return image


class CameraPictures(NamedTuple):
    """What a policy saw over time, as ``camera_pictures`` draws it."""

    pictures: list[np.ndarray]
    """(H, frames x W, 3) uint8 per time: the stacked frames side by side, oldest first."""
    caption: list[str]
    """What they are, which frame is oldest, how depth maps to grey."""
    frames: int
    """Frames per picture."""


def camera_pictures(observations: np.ndarray, image: str) -> CameraPictures:
    """One env's camera observations over time (T, channels x frames, H, W) as pictures, its stacked frames side by
    side, oldest first; depth in grey, near bright, nothing black; with their caption."""
    steps, stacked, height, width = observations.shape
    frames = stacked // (3 if image == "rgb" else 1)
    caption = [f"the policy's input: its last {frames} {'colour' if image == 'rgb' else 'depth'} frames "
               f"({width}x{height}), oldest left, one env step apart"]
    if image == "rgb":
        pictures = observations.reshape(steps, -1, 3, height, width).transpose(0, 1, 3, 4, 2)
    else:
        far_m = max(float(observations.max()), 1e-6)
        grey = np.where(observations > 0, 255 * (1 - 0.7 * observations / far_m), 0).astype(np.uint8)
        pictures = np.repeat(grey[..., None], 3, axis=-1)
        caption.append(f"depth in grey: near white, {far_m:.1f} m dark grey, black: no surface")
    return CameraPictures([np.concatenate(list(stack), axis=1) for stack in pictures], caption, frames)


def beside(picture: Image.Image, camera: np.ndarray, caption: Sequence[str] = (), frames: int = 1) -> Image.Image:
    """``camera`` (H, frames x W, 3) scaled to the height of ``picture`` (pixels kept square and sharp), right of it,
    with ``caption`` above it and each of its ``frames`` labelled by its age in env steps below."""
    font = ImageFont.load_default(size=12)
    line_px = 15
    scale = max(1, picture.height // camera.shape[0])
    shown = Image.fromarray(camera).resize((camera.shape[1] * scale, camera.shape[0] * scale), Image.NEAREST)
    top = line_px * len(caption)
    width = picture.width + max(shown.width, max((int(font.getlength(line)) + 8 for line in caption), default=0))
    both = Image.new("RGB", (width, max(picture.height, top + shown.height + (line_px if caption else 0))),
                     BACKGROUND)
    both.paste(picture, (0, 0))
    both.paste(shown, (picture.width, top))
    draw = ImageDraw.Draw(both)
    for row, line in enumerate(caption):
        draw.text((picture.width + 4, row * line_px), line, fill=INK, font=font)
    if caption:
        frame_px = shown.width // frames
        for k in range(frames):
            age = frames - 1 - k
            draw.text((picture.width + k * frame_px + 4, top + shown.height),
                      "now" if age == 0 else f"{age} step{'s' if age > 1 else ''} earlier", fill=INK, font=font)
    return both


def write_gif(path: Path, images: list[Image.Image], frame_dt_s: float,
              cameras: CameraPictures | None = None) -> Path:
    """``images`` as an animated GIF, ``frame_dt_s`` apart, with the policy's ``cameras`` (``camera_pictures``, one
    per image) beside them where given. The frames share the 32-colour palette of the first (every frame has the same
    flat colours): mapping onto one palette is cheaper than choosing a palette per frame; with camera pictures, 256
    colours. Frames are written without Pillow's ``optimize`` (which makes each frame's unchanged pixels transparent):
    quicker, for a slightly larger file (docs/benchmarks.md)."""
    if cameras is not None:
        images = [beside(image, camera, cameras.caption, cameras.frames)
                  for image, camera in zip(images, cameras.pictures)]
    palette = images[0].convert("P", palette=Image.Palette.ADAPTIVE, colors=32 if cameras is None else 256)
    images = [image.quantize(palette=palette, dither=Image.Dither.NONE) for image in images]
    duration_ms = max(20, int(round(1000 * frame_dt_s)))

    def save(tmp):
        images[0].save(tmp, format="GIF", save_all=True, append_images=images[1:], duration=duration_ms, loop=0,
                       optimize=False)

    return atomic_write(path, save)


class EnvFrames(Sequence):
    """``frames[i]``: env ``i`` of a ``BatchedEnv`` now, as an (H, W, 3) uint8 array, drawn when asked (a slice gives a
    list of them) (a vector
    env's ``render()`` returns this sequence: rendering one env costs one picture, not ``num_envs``). The framing is
    fixed at construction from env 0: the widest static shape across, the moving shapes' reach up and down."""

    def __init__(self, env: BatchedEnv, width_px: int = 640):
        self.env = env
        self._geometries: dict[tuple[int, int], Geometry] = {}
        first = self._geometry(0)
        with warp_output(env.cfg.verbose):  # the library prints nothing: Newton's kinematics module loads here
            self.view = SideView.around(first, [first.body_transforms(env.scene.state_0)], width_px, reach=True)

    def _shard(self, index: int):
        return next(s for s in self.env.shards if s.start <= index < s.stop)

    def _geometry(self, index: int) -> Geometry:
        shard = self._shard(index)
        key = (shard.index, index - shard.start)
        if key not in self._geometries:
            self._geometries[key] = Geometry(shard.scene.model, world=index - shard.start)
        return self._geometries[key]

    def __len__(self) -> int:
        return self.env.num_envs

    def __getitem__(self, index: int | slice) -> np.ndarray | list[np.ndarray]:
        if isinstance(index, slice):
            return [self[i] for i in range(*index.indices(len(self)))]
        if not -len(self) <= index < len(self):
            raise IndexError(f"env {index} of {len(self)}")
        index %= len(self)
        transforms = self._geometry(index).body_transforms(self._shard(index).scene.state_0)
        return np.asarray(self.view.image(transforms))
