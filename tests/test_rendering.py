"""rgb_array rendering through gymnasium's and SB3's video recorders, and frames that show the state."""

import math

import gymnasium as gym
import imageio.v2 as imageio
import numpy as np
import pytest
import torch
from gymnasium.wrappers import RecordVideo
from gymnasium.wrappers.vector import RecordVideo as VectorRecordVideo
from stable_baselines3.common.vec_env import VecVideoRecorder

import cartpole_warp
from cartpole_warp.viz.frames import EnvFrames
from cartpole_warp.wrappers.sb3 import CartpoleSb3VecEnv

VIDEO_STEPS = 37
"""Steps recorded; the recorders add the frame before the first step. 38 frames at 60 fps: moviepy, which both
recorders use, writes all of them (for some other counts it drops the last)."""


def decoded_frames(folder):
    (video,) = folder.glob("*.mp4")
    return [frame for frame in imageio.get_reader(video)]  # list() asks the reader's length, which is infinite


def test_record_video_around_the_single_env(tmp_path):
    env = gym.make("cartpole_warp/CartpoleTutorial-v0", render_mode="rgb_array")
    assert env.metadata["render_fps"] == 60 and env.metadata["render_modes"] == ["rgb_array"]
    env = RecordVideo(env, str(tmp_path), episode_trigger=lambda episode: True, video_length=VIDEO_STEPS)
    env.reset(seed=0)
    for _ in range(VIDEO_STEPS + 5):
        env.step(np.zeros(1, np.float32))
    env.close()
    frames = decoded_frames(tmp_path)
    assert len(frames) == VIDEO_STEPS + 1 and frames[0].shape[2] == 3


def test_record_video_around_the_vector_env_draws_only_what_it_records(tmp_path):
    envs = gym.make_vec("cartpole_warp/Cartpole-v0", num_envs=8, vectorization_mode="vector_entry_point",
                        render_mode="rgb_array")
    frames = envs.render()
    assert isinstance(frames, EnvFrames) and len(frames) == 8 and frames[7].dtype == np.uint8
    envs = VectorRecordVideo(envs, str(tmp_path), record_first_only=True, step_trigger=lambda step: step == 0,
                             video_length=VIDEO_STEPS)
    envs.reset(seed=0)
    for _ in range(VIDEO_STEPS + 5):
        envs.step(np.zeros((8, 1), np.float32))
    envs.close()
    assert len(decoded_frames(tmp_path)) == VIDEO_STEPS + 1


def test_sb3_vec_video_recorder(tmp_path):
    venv = CartpoleSb3VecEnv(cartpole_warp.make_env(num_envs=8), render_mode="rgb_array")
    assert venv.render().shape == venv.get_images()[0].shape and len(venv.get_images()) == 8
    venv = VecVideoRecorder(venv, str(tmp_path), record_video_trigger=lambda step: step == 0,
                            video_length=VIDEO_STEPS)
    venv.reset()
    for _ in range(VIDEO_STEPS + 5):
        venv.step(np.zeros((8, 1), np.float32))
    venv.close()
    assert len(decoded_frames(tmp_path)) == VIDEO_STEPS + 1


def columns_of(frame, rgb):
    """Mean column of the pixels within 30 of ``rgb``."""
    hits = np.argwhere((np.abs(frame.astype(int) - np.array(rgb)) < 30).all(axis=2))
    assert len(hits) > 20, f"no pixels of colour {rgb}"
    return hits[:, 1].mean()


@pytest.mark.parametrize("pole_angle", [0.6, -0.6])
def test_a_frame_shows_the_pole_where_the_state_puts_it(pole_angle):
    env = cartpole_warp.make_env(num_envs=3)
    frames = EnvFrames(env)
    states = torch.tensor([[0.0, 0.0, 0.0, 0.0], [1.0, 0.0, pole_angle, 0.0], [-1.0, 0.0, 0.0, 0.0]])
    env.set_state(states)
    colours = {box.name: tuple(round(255 * c) for c in box.color_srgb) for box in frames._geometry(0).boxes}
    pole, cart = colours["pole"], colours["cart"]
    # the pole turns about +X: its centre of mass sits at y = cart_pos - l sin(pole_angle) (tests/test_physics.py)
    offset = columns_of(frames[1], pole) - columns_of(frames[1], cart)
    assert math.copysign(1, offset) == -math.copysign(1, pole_angle) and abs(offset) > 10
    assert columns_of(frames[1], cart) > columns_of(frames[0], cart) > columns_of(frames[2], cart), "cart_pos"
    upright = columns_of(frames[0], pole) - columns_of(frames[0], cart)
    assert abs(upright) < abs(offset)
