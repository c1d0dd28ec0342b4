"""Headless pictures of the cartpole: a GIF side view, a time-sampled USD recording and the learning curve.

Geometry comes from the Newton model (box shapes, their body, size, offset and colour), motion from body
transforms recorded per env step (``Geometry.body_transforms``), so nothing here knows cartpole dimensions.
Everything renders on a CPU without a display (Pillow for images, usd-core for the stage).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import warp as wp
from PIL import Image, ImageDraw, ImageFont

import newton

from .runs import atomic_write

BACKGROUND = (250, 250, 250)
INK = (40, 40, 40)


def _quat_rotate(q: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Rotate vectors ``v`` (..., 3) by quaternions ``q`` (..., 4) stored (x, y, z, w)."""
    xyz, w = q[..., :3], q[..., 3:4]
    t = 2.0 * np.cross(xyz, v)
    return v + w * t + np.cross(xyz, t)


def _quat_mul(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Hamilton product of (x, y, z, w) quaternions."""
    ax, ay, az, aw = np.moveaxis(a, -1, 0)
    bx, by, bz, bw = np.moveaxis(b, -1, 0)
    return np.stack([aw * bx + ax * bw + ay * bz - az * by, aw * by - ax * bz + ay * bw + az * bx,
                     aw * bz + ax * by - ay * bx + az * bw, aw * bw - ax * bx - ay * by - az * bz], axis=-1)


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


def write_usd(path: Path, geometry: Geometry, frames: np.ndarray, env_dt: float) -> Path:
    """A USD stage with one Xform per body whose translate/orient are time-sampled per env step (time code =
    step index, ``timeCodesPerSecond`` = 1 / env_dt), and the boxes as coloured Cubes; no physics schemas."""
    from pxr import Gf, Tf, Usd, UsdGeom

    stage = Usd.Stage.CreateInMemory()
    UsdGeom.SetStageUpAxis(stage, UsdGeom.Tokens.z)
    UsdGeom.SetStageMetersPerUnit(stage, 1.0)
    root = UsdGeom.Xform.Define(stage, "/cartpole")
    stage.SetDefaultPrim(root.GetPrim())
    fps = 1.0 / env_dt
    stage.SetTimeCodesPerSecond(fps)
    stage.SetFramesPerSecond(fps)
    stage.SetStartTimeCode(0)
    stage.SetEndTimeCode(len(frames) - 1)

    def quat(q):
        return Gf.Quatf(float(q[3]), float(q[0]), float(q[1]), float(q[2]))

    body_paths = []
    for b, name in enumerate(geometry.body_names):
        xform = UsdGeom.Xform.Define(stage, root.GetPath().AppendChild(Tf.MakeValidIdentifier(name)))
        translate, orient = xform.AddTranslateOp(), xform.AddOrientOp()
        for t, transforms in enumerate(frames):
            translate.Set(Gf.Vec3d(*transforms[b, :3]), Usd.TimeCode(t))
            orient.Set(quat(transforms[b, 3:]), Usd.TimeCode(t))
        body_paths.append(xform.GetPath())
    for box in geometry.boxes:
        parent = body_paths[box.body] if box.body >= 0 else root.GetPath()
        cube = UsdGeom.Cube.Define(stage, parent.AppendChild(Tf.MakeValidIdentifier(box.name)))
        cube.CreateSizeAttr(1.0)
        cube.AddTranslateOp().Set(Gf.Vec3d(*box.local_transform[:3]))
        cube.AddOrientOp().Set(quat(box.local_transform[3:]))
        cube.AddScaleOp().Set(Gf.Vec3f(*(2.0 * box.half_extents_m)))
        linear = [c**2.2 for c in box.color_srgb]
        cube.CreateDisplayColorAttr([Gf.Vec3f(*linear)])
    return atomic_write(path, lambda tmp: stage.GetRootLayer().Export(tmp))


def plot_learning_curve(path: Path, history: list[dict], panels: list[tuple[str, str, float | None]],
                        width_px: int = 900, panel_height_px: int = 260) -> Path:
    """PNG with one line plot per panel (title, history key, threshold line or None) against the iteration."""
    font = ImageFont.load_default(size=13)
    left, right, top, bottom = 70, 20, 28, 36
    image = Image.new("RGB", (width_px, panel_height_px * len(panels)), "white")
    draw = ImageDraw.Draw(image)
    for p, (title, key, threshold) in enumerate(panels):
        y0 = p * panel_height_px
        points = [(h["iteration"], h[key]) for h in history if h.get(key) is not None]
        x_lo, x_hi = (points[0][0], max(points[-1][0], points[0][0] + 1)) if points else (0, 1)
        values = [v for _, v in points] + ([threshold] if threshold is not None else [])
        v_lo, v_hi = (min(values), max(values)) if values else (0.0, 1.0)
        if v_hi - v_lo < 1e-9:
            v_lo, v_hi = v_lo - 1.0, v_hi + 1.0
        pad = 0.05 * (v_hi - v_lo)
        v_lo, v_hi = v_lo - pad, v_hi + pad
        box = (left, y0 + top, width_px - right, y0 + panel_height_px - bottom)

        def to_px(x, v, box=box, x_lo=x_lo, x_hi=x_hi, v_lo=v_lo, v_hi=v_hi):
            return (box[0] + (x - x_lo) / (x_hi - x_lo) * (box[2] - box[0]),
                    box[3] - (v - v_lo) / (v_hi - v_lo) * (box[3] - box[1]))

        draw.rectangle(box, outline=INK)
        draw.text((left, y0 + 6), title, fill=INK, font=font)
        for k in range(5):
            v = v_lo + (v_hi - v_lo) * k / 4
            _, y = to_px(x_lo, v)
            draw.line([(box[0] - 4, y), (box[0], y)], fill=INK)
            draw.text((4, y - 7), f"{v:8.3g}", fill=INK, font=font)
            x_tick = x_lo + (x_hi - x_lo) * k / 4
            x, _ = to_px(x_tick, v_lo)
            draw.line([(x, box[3]), (x, box[3] + 4)], fill=INK)
            draw.text((x - 10, box[3] + 6), f"{x_tick:.0f}", fill=INK, font=font)
        draw.text(((box[0] + box[2]) / 2 - 25, box[3] + 20), "iteration", fill=INK, font=font)
        if threshold is not None:
            draw.line([to_px(x_lo, threshold), to_px(x_hi, threshold)], fill=(200, 60, 60), width=1)
        if len(points) > 1:
            draw.line([to_px(x, v) for x, v in points], fill=(30, 90, 200), width=2)
        elif points:
            x, y = to_px(*points[0])
            draw.ellipse((x - 2, y - 2, x + 2, y + 2), fill=(30, 90, 200))
    return atomic_write(path, lambda tmp: image.save(tmp, format="PNG"))
