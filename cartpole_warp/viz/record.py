"""Recording env 0 of a rollout: a GIF side view, an MP4 of the same pictures, a time-sampled USD stage (Newton's
``ViewerUSD``) and, where asked (the viser extra), a ``.viser`` recording for the browser.

    recorder = Recorder.of_env(env, out_dir)
    rollout(env, policy, steps, on_step=recorder)
    recorder.close()            # cartpole.gif, cartpole.mp4 (with the video extra), cartpole.usda (usdview plays it)
"""

from __future__ import annotations

import importlib.util
import os
from collections.abc import Callable, Iterable
from pathlib import Path

import numpy as np
from newton.viewer import ViewerUSD

from ..engine.env import BatchedEnv
from ..engine.scene import Scene
from ..settings.files import atomic_write
from . import prepare_viewers
from .frames import Geometry, SideView, camera_pictures, write_gif

VIDEO_EXTRA = "pip install 'cartpole_warp[video]'"
GIF_STRIDE = 2
"""The GIFs show every this many env steps (the MP4 every one)."""


def video_available() -> bool:
    """Whether MP4s can be written: imageio with its ffmpeg wheel (the video extra) is installed."""
    return importlib.util.find_spec("imageio") is not None and importlib.util.find_spec("imageio_ffmpeg") is not None


def write_mp4(path: Path, images: Iterable[np.ndarray], fps: float) -> Path:
    """``images`` (H, W, 3) uint8 as an H.264 MP4 at ``fps``, every image one frame, taken one at a time (imageio +
    ffmpeg; moviepy, which RecordVideo uses, drops the last frame for some counts and rates)."""
    import imageio.v2 as imageio

    def write(tmp):
        with imageio.get_writer(tmp, format="FFMPEG", fps=fps, codec="libx264", macro_block_size=2) as video:
            for image in images:
                video.append_data(image)

    return atomic_write(path, write)


class Recorder:
    """Called once per env step (``recorder(step)``), it records the bodies of env 0 of ``scene``.
    ``video_length``: env steps in the MP4 (None: all); ``viser``: also a ``.viser`` recording; ``camera``: what the
    policy sees (env 0's camera observation, a numpy array, and the kind of image, 'rgb' or 'depth'), recorded too and
    drawn beside the side view in ``policy_view.gif``; ``final_state``: env 0's joint state where its episode ended
    in the step just taken, else None (``BatchedEnv.final_state_buf``): that step's frame shows the episode's end, not
    the next episode's start that the scene already holds; ``name``: the files' stem; ``usd``: write the USD stage."""

    def __init__(self, scene: Scene, env_dt: float, out_dir: Path, video_length: int | None = None,
                 viser: bool = False, camera: tuple[Callable[[], np.ndarray], str] | None = None,
                 final_state: Callable[[], np.ndarray | None] | None = None, name: str = "cartpole",
                 usd: bool = True):
        self.scene, self.env_dt, self.out_dir, self.video_length = scene, env_dt, Path(out_dir), video_length
        self.camera, self.final_state, self.name = camera, final_state, name
        self._ended_state = None
        self.camera_frames: list[np.ndarray] = []
        self.geometry = Geometry(scene.model)
        self.frames: list[np.ndarray] = []
        self.fps = max(1, round(1.0 / env_dt))
        """Time codes per second of the USD stage: one time code per env step."""
        self.out_dir.mkdir(parents=True, exist_ok=True)
        self._usd_tmp = self.out_dir / f".{name}.usda.tmp.usda"
        self.usd = None
        if usd:
            prepare_viewers()
            self.usd = ViewerUSD(str(self._usd_tmp), fps=self.fps, num_frames=None)
            self.usd.set_model(scene.model)
            self.usd.set_visible_worlds([0])
        self.viser = None
        if viser:
            from .web import Recording

            self.viser = Recording(scene, self.out_dir / f"{name}.viser", env_dt)

    @classmethod
    def of_env(cls, env: BatchedEnv, out_dir: Path, policy_view: bool = True, **kwargs) -> Recorder:
        """A recorder of env 0 of ``env``: its side view, its end-of-episode states and, where the policy sees
        frames and ``policy_view``, its camera's; ``kwargs``: the other arguments (``video_length``, ``viser``,
        ``name``, ``usd``)."""
        camera = ((lambda: env.obs_buf[0].to("cpu", copy=True).numpy(), env.cfg.camera.image)
                  if env.sees_images and policy_view else None)

        def final_state() -> np.ndarray | None:
            ended = bool(env.terminated_buf[0] | env.truncated_buf[0])
            return env.final_state_buf[0].cpu().numpy() if ended else None

        return cls(env.scene, env.env_dt, out_dir, camera=camera, final_state=final_state, **kwargs)

    def __call__(self, step: int):
        ended = self.final_state() if self.final_state is not None and step > 0 else None
        state = self.scene.state_0 if ended is None else self._state_at(ended)
        self.frames.append(self.geometry.body_transforms(state))
        if self.usd is not None:
            self.usd.begin_frame(step / self.fps)
            self.usd.log_state(state)
            self.usd.end_frame()
        if self.camera is not None and step % GIF_STRIDE == 0:  # what policy_view.gif shows
            self.camera_frames.append(self.camera[0]())
        if self.viser is not None:
            self.viser(step)

    def _state_at(self, role_state: np.ndarray):
        """A Newton state of the scene with env 0's joint roles at ``role_state`` (per role: position, velocity)."""
        if self._ended_state is None:
            self._ended_state = self.scene.model.state()
        joint_q, joint_qd = self.scene.state_0.joint_q.numpy().copy(), self.scene.state_0.joint_qd.numpy().copy()
        for role, dof in enumerate(self.scene.role_dofs):
            joint_q[dof], joint_qd[dof] = role_state[2 * role], role_state[2 * role + 1]
        self._ended_state.joint_q.assign(joint_q)
        self._ended_state.joint_qd.assign(joint_qd)
        return self._ended_state

    def close(self) -> list[Path]:
        """Write the GIF, the MP4 (when the video extra is installed), the USD stage and the viser recording (where
        asked); return their paths."""
        recordings = []
        if self.usd is not None:
            self.usd.close()
            recordings.append(self.out_dir / f"{self.name}.usda")
            os.replace(self._usd_tmp, recordings[-1])
        if self.viser is not None:
            self.viser.close()
            recordings.append(self.out_dir / f"{self.name}.viser")
        view = SideView.around(self.geometry, self.frames, width_px=800)

        def picture(step: int):
            return view.image(self.frames[step], f"t = {step * self.env_dt:5.2f} s")

        gifs = {step: picture(step) for step in range(0, len(self.frames), GIF_STRIDE)}  # drawn once for GIFs and MP4
        written = [write_gif(self.out_dir / f"{self.name}.gif", list(gifs.values()), GIF_STRIDE * self.env_dt)]
        if self.camera is not None:
            cameras = camera_pictures(np.stack(self.camera_frames), self.camera[1])
            written.append(write_gif(self.out_dir / "policy_view.gif", list(gifs.values()), GIF_STRIDE * self.env_dt,
                                     cameras=cameras))
        if video_available():
            shown = range(min(len(self.frames), self.video_length or len(self.frames)))
            written.append(write_mp4(self.out_dir / f"{self.name}.mp4",
                                     (np.asarray(gifs[step] if step in gifs else picture(step)) for step in shown),
                                     1.0 / self.env_dt))
        return [*written, *recordings]
