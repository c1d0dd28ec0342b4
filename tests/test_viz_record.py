"""Recordings of play.py (``viz/record.py``): the frame of the step that ends env 0's episode shows the state the
episode ended at, not the next episode's start that the env has already reset to."""

import functools

import numpy as np
import pytest

from cartpole_warp.evaluation.rollouts import first_episodes, zero_policy
from cartpole_warp.viz.frames import Geometry
from cartpole_warp.viz.record import Recorder

STEPS = 6


@pytest.mark.parametrize("task", ["cartpole-balance", "cart-double-pole-balance", "cartpole-swingup"])
def test_the_frame_of_an_episodes_last_step_shows_its_end_not_the_next_start(make, tmp_path, task):
    """The same starts (seed 0) with a time limit of STEPS steps and with the task's own: the first recording's last
    frame is the second run's state after STEPS steps."""
    reference = make(2, task_name=task)
    ending = make(2, task_name=task, task={"episode_length_s": STEPS * reference.env_dt})
    assert ending.max_episode_length == STEPS
    policy = functools.partial(zero_policy, num_actions=reference.num_actions)
    recorder = Recorder.of_env(ending, tmp_path)
    first_episodes(ending, policy, STEPS, on_step=recorder, seed=0)
    geometry = Geometry(reference.scene.model)
    expected = []
    first_episodes(reference, policy, STEPS, seed=0,
                   on_step=lambda step: expected.append(geometry.body_transforms(reference.scene.state_0)))
    np.testing.assert_allclose(np.stack(recorder.frames), np.stack(expected), atol=1e-5)
    restarted = geometry.body_transforms(ending.scene.state_0)
    assert not np.allclose(restarted, expected[-1], atol=1e-3), "the env holds the next episode's start"



def test_the_policy_view_says_what_it_shows():
    """policy_view.gif's panel: the policy's input, which frame is oldest, how depth maps to grey."""
    from cartpole_warp.viz.frames import camera_pictures

    depth = np.zeros((2, 3, 8, 8), dtype=np.float32)
    depth[:, :, 4, 4] = [[1.0, 2.0, 4.0]]
    pictures, caption, frames = camera_pictures(depth, "depth")
    assert frames == 3 and pictures[0].shape == (8, 24, 3)
    assert caption == ["the policy's input: its last 3 depth frames (8x8), oldest left, one env step apart",
                       "depth in grey: near white, 4.0 m dark grey, black: no surface"]
    assert pictures[0][4, 4, 0] > pictures[0][4, 20, 0] > pictures[0][0, 0, 0] == 0, "near brighter, nothing black"
    assert camera_pictures(np.zeros((1, 9, 8, 8), np.uint8), "rgb").caption[0].startswith(
        "the policy's input: its last 3 colour frames (8x8), oldest left")
