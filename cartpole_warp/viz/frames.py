"""A GIF side view of one env, drawn with Pillow (no GL, no display).

Geometry comes from the Newton model (box shapes, their body, size, offset and colour), motion from body
transforms recorded per env step (``Geometry.body_transforms``), so nothing here knows cartpole dimensions.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import newton
import numpy as np
import warp as wp
from PIL import Image, ImageDraw, ImageFont

from ..rl.runs import atomic_write

BACKGROUND = (250, 250, 250)
INK = (40, 40, 40)


def _quat_rotate(q: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Rotate vectors ``v`` (..., 3) by quaternions ``q`` (..., 4) stored (x, y, z, w)."""
    xyz, w = q[..., :3], q[..., 3:4]
    t = 2.0 * np.cross(xyz, v)
    return v + w * t + np.cross(xyz, t)


@dataclass
class Box:
    """One box shape of the recorded env."""

    name: str
    body: int
    """Index into the recorded bodies, -1 for a static shape."""
    half_extents_m: np.ndarray
    local_transform: np.ndarray
    """(7,) position (m) and (x, y, z, w) quaternion relative to the body (to the world if static)."""
    color_srgb: tuple[float, float, float]


class Geometry:
    """The boxes and bodies of one env (world) of a Newton model, and their poses over time."""

    def __init__(self, model: newton.Model, world: int = 0):
        self.model = model
        body_world = model.body_world.numpy()
        self.body_ids = np.flatnonzero(body_world == world)
        self.body_names = [model.body_label[i].rsplit("/", 1)[-1] for i in self.body_ids]
        shape_world, shape_body = model.shape_world.numpy(), model.shape_body.numpy()
        kinds, scales = model.shape_type.numpy(), model.shape_scale.numpy()
        transforms, colors = model.shape_transform.numpy(), model.shape_color.numpy()
        body_index = {int(b): i for i, b in enumerate(self.body_ids)}
        self.boxes = []
        for s in np.flatnonzero(shape_world == world):
            if kinds[s] != newton.GeoType.BOX:
                continue
            parts = model.shape_label[s].strip("/").split("/")
            body = body_index.get(int(shape_body[s]), -1)
            self.boxes.append(Box(name=parts[-2] if body < 0 and len(parts) > 1 else parts[-1], body=body,
                                  half_extents_m=scales[s].astype(np.float64),
                                  local_transform=transforms[s].astype(np.float64),
                                  color_srgb=tuple(float(c) for c in colors[s])))
        mask = np.zeros(model.articulation_count, dtype=bool)
        articulation_world = model.articulation_world.numpy()
        mask[articulation_world == world] = True
        self._fk_mask = wp.array(mask, dtype=wp.bool, device=model.device)

    def body_transforms(self, state: newton.State) -> np.ndarray:
        """(bodies, 7) world transforms of the env's bodies, from the state's joint coordinates."""
        newton.eval_fk(self.model, state.joint_q, state.joint_qd, state, mask=self._fk_mask)
        return state.body_q.numpy()[self.body_ids].astype(np.float64)

    def box_corners(self, box: Box, body_transform: np.ndarray | None) -> np.ndarray:
        """(8, 3) world corners of ``box`` given its body's transform (None for a static box)."""
        signs = np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)], dtype=np.float64)
        local = box.local_transform
        points = _quat_rotate(np.broadcast_to(local[3:], (8, 4)), signs * box.half_extents_m) + local[:3]
        if body_transform is not None:
            points = _quat_rotate(np.broadcast_to(body_transform[3:], (8, 4)), points) + body_transform[:3]
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


def write_gif(path: Path, geometry: Geometry, frames: np.ndarray, env_dt: float, width_px: int = 800,
              frame_stride: int = 2) -> Path:
    """Side view (the rail's Y axis to the right, Z up) of ``frames`` (T, bodies, 7) as an animated GIF."""
    frames = frames[::frame_stride]
    polygons = []
    for transforms in frames:
        polygons.append([(box, geometry.box_corners(box, transforms[box.body] if box.body >= 0 else None)[:, 1:])
                         for box in geometry.boxes])
    everything = np.concatenate([corners for frame in polygons for _, corners in frame])
    low, high = everything.min(axis=0), everything.max(axis=0)
    margin = 0.05 * (high - low).max()
    low, high = low - margin, high + margin
    scale = width_px / (high[0] - low[0])
    height_px = max(1, int(math.ceil((high[1] - low[1]) * scale)) + 24)
    font = ImageFont.load_default(size=14)

    def to_px(yz):
        return [((y - low[0]) * scale, height_px - (z - low[1]) * scale) for y, z in yz]

    images = []
    for i, frame in enumerate(polygons):
        image = Image.new("RGB", (width_px, height_px), BACKGROUND)
        draw = ImageDraw.Draw(image)
        for box, corners in frame:
            fill = tuple(int(255 * c) for c in box.color_srgb)
            draw.polygon(to_px(_convex_hull(corners)), fill=fill, outline=INK)
        draw.text((8, 4), f"t = {i * frame_stride * env_dt:5.2f} s", fill=INK, font=font)
        images.append(image.convert("P", palette=Image.Palette.ADAPTIVE, colors=32))
    duration_ms = max(20, int(round(1000 * env_dt * frame_stride)))

    def save(tmp):
        images[0].save(tmp, format="GIF", save_all=True, append_images=images[1:], duration=duration_ms, loop=0)

    return atomic_write(path, save)
