"""rgb_array rendering through gymnasium's and SB3's video recorders, and frames that show the state; for every
registered task."""

import math

import gymnasium as gym
import numpy as np
import pytest
import torch
from conftest import SB3_EXTRA, optional_module
from gymnasium.wrappers import RecordVideo
from gymnasium.wrappers.vector import RecordVideo as VectorRecordVideo

import cartpole_warp
from cartpole_warp.viz.frames import EnvFrames
from cartpole_warp.wrappers.gymnasium import env_ids

TASKS = cartpole_warp.tasks.names()
IDS = env_ids()
"""id -> (task name, preset), for every registered task."""
TASK_IDS = {task: next(env_id for env_id, (name, preset) in IDS.items() if name == task and preset is None)
            for task in TASKS}
"""Each task's id with its own defaults."""
VIDEO_STEPS = 37
"""Steps recorded; the recorders add the frame before the first step. 38 frames at 60 and 50 fps: moviepy, which
both recorders use, writes all of them (for some other counts it drops the last)."""


GYM_VIDEO_EXTRA = "pip install -e '.[gym-video]'"


def recorders_write_video():
    """Skip unless the recorders' moviepy (and imageio, which reads their MP4s back) is installed."""
    optional_module("moviepy", GYM_VIDEO_EXTRA)


def decoded_frames(folder):
    import imageio.v2 as imageio  # moviepy's dependency

    (video,) = folder.glob("*.mp4")
    return [frame for frame in imageio.get_reader(video)]  # list() asks the reader's length, which is infinite


def expected_fps(env_id):
    task, preset = IDS[env_id]
    return round(1.0 / cartpole_warp.tasks.env_config(task, preset).sim.env_dt)


@pytest.mark.parametrize("env_id", IDS)
def test_record_video_around_the_single_env(env_id, tmp_path):
    recorders_write_video()
    env = gym.make(env_id, render_mode="rgb_array")
    assert env.metadata["render_fps"] == expected_fps(env_id) and env.metadata["render_modes"] == ["rgb_array"]
    assert expected_fps(env_id) == (60 if IDS[env_id][0] in ("cartpole-balance", "cartpole-balance-sparse",
                                                             "cartpole-balance-rgb", "cartpole-balance-depth",
                                                             "cart-double-pole-balance-rgb",
                                                             "cart-double-pole-balance") else 50)
    env = RecordVideo(env, str(tmp_path), episode_trigger=lambda episode: True, video_length=VIDEO_STEPS)
    env.reset(seed=0)
    for _ in range(VIDEO_STEPS + 5):
        env.step(np.zeros(1, np.float32))
    env.close()
    frames = decoded_frames(tmp_path)
    assert len(frames) == VIDEO_STEPS + 1 and frames[0].shape[2] == 3
    assert frames[0].std() > 10, "the frames show something"


@pytest.mark.parametrize("task", TASKS)
def test_record_video_around_the_vector_env_draws_only_what_it_records(task, tmp_path):
    recorders_write_video()
    envs = gym.make_vec(TASK_IDS[task], num_envs=8, vectorization_mode="vector_entry_point", render_mode="rgb_array")
    assert envs.metadata["render_fps"] == expected_fps(TASK_IDS[task])
    frames = envs.render()
    assert isinstance(frames, EnvFrames) and len(frames) == 8 and frames[7].dtype == np.uint8
    envs = VectorRecordVideo(envs, str(tmp_path), record_first_only=True, step_trigger=lambda step: step == 0,
                             video_length=VIDEO_STEPS)
    envs.reset(seed=0)
    for _ in range(VIDEO_STEPS + 5):
        envs.step(np.zeros((8, 1), np.float32))
    envs.close()
    assert len(decoded_frames(tmp_path)) == VIDEO_STEPS + 1


@pytest.mark.parametrize("task", TASKS)
def test_sb3_vec_video_recorder(task, tmp_path):
    recorders_write_video()
    VecVideoRecorder = optional_module("stable_baselines3.common.vec_env", SB3_EXTRA).VecVideoRecorder
    from cartpole_warp.wrappers.sb3 import TaskSb3VecEnv

    venv = TaskSb3VecEnv(cartpole_warp.tasks.make(task, num_envs=8), render_mode="rgb_array")
    assert venv.render().shape == venv.get_images()[0].shape and len(venv.get_images()) == 8
    venv = VecVideoRecorder(venv, str(tmp_path), record_video_trigger=lambda step: step == 0,
                            video_length=VIDEO_STEPS)
    venv.reset()
    for _ in range(VIDEO_STEPS + 5):
        venv.step(np.zeros((8, 1), np.float32))
    venv.close()
    assert len(decoded_frames(tmp_path)) == VIDEO_STEPS + 1


def pixels_of(frame, rgb):
    """(H, W) bool: the pixels within 30 of ``rgb``."""
    return (np.abs(frame.astype(int) - np.array(rgb)) < 30).all(axis=2)


def mean_column(mask):
    assert mask.sum() > 20, "too few pixels"
    return np.argwhere(mask)[:, 1].mean()


def mean_row(mask):
    assert mask.sum() > 20, "too few pixels"
    return np.argwhere(mask)[:, 0].mean()


@pytest.mark.parametrize("pole_angle", [0.6, -0.6])
@pytest.mark.parametrize("task", TASKS)
def test_a_frame_shows_the_pole_where_the_state_puts_it(task, pole_angle):
    """Located by colour; where the cart and the pole share one (the swing-up stage), the pole is told apart by
    what differs from the frame with the pole upright over the cart at the same place. The double pole's second pole
    (same colour) stays in line with the first."""
    env = cartpole_warp.tasks.make(task, num_envs=5)
    frames = EnvFrames(env)
    states = torch.tensor([[0.0, 0.0, 0.0, 0.0], [0.0, 0.0, pole_angle, 0.0], [1.0, 0.0, 0.0, 0.0],
                           [-1.0, 0.0, 0.0, 0.0], [0.0, 0.0, math.pi, 0.0]])
    env.set_state(torch.nn.functional.pad(states, (0, 2 * len(env.joint_roles) - 4)))  # further poles straight on
    model = env.scene.model
    pole_body = model.body_label[model.joint_child.numpy()[env.scene.role_joints[1]]].rsplit("/", 1)[-1]
    colours = {shape.name: tuple(round(255 * c) for c in shape.color_srgb) for shape in frames._geometry(0).shapes}
    pole, cart, rail = colours[pole_body], colours["cart"], colours["rail"]
    upright = pixels_of(frames[0], pole)  # the upright pole (and the cart where it has the pole's colour)
    tilted = pixels_of(frames[1], pole) & ~upright
    hanging = pixels_of(frames[4], pole) & ~upright
    # the pole turns about +X: its centre of mass sits at y = cart_pos - l sin(pole_angle) (tests/test_physics.py)
    offset = mean_column(tilted) - mean_column(upright)
    assert math.copysign(1, offset) == -math.copysign(1, pole_angle) and abs(offset) > 10
    rail_row = mean_row(pixels_of(frames[0], rail))
    assert mean_row(tilted) < rail_row - 10 < rail_row + 10 < mean_row(hanging), "angle 0 is up, pi down"
    assert abs(mean_column(hanging) - mean_column(upright)) < 3
    columns = [mean_column(pixels_of(frames[i], cart)) for i in (2, 0, 3)]
    assert columns[0] > columns[1] + 10 > columns[2] + 20, "cart_pos 1, 0, -1 from right to left"
