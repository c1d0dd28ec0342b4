"""The double pole's own rules, against independent references: its reward and ends against Gymnasium's
``InvertedDoublePendulum`` shape written out here from the spec, and the tip they use against the tip of pole 2 as
Newton's forward kinematics places it (which checks the angle conventions)."""

import math

import newton
import numpy as np
import pytest
import torch

import cartpole_warp
from cartpole_warp.settings.config import ConfigError

TASK = "cart-double-pole-balance"
STATES = torch.tensor([[0.0, 0.0, 0.0, 0.0, 0.0, 0.0], [0.4, 0.3, 0.1, -0.5, -0.15, 0.8],
                       [-1.0, -0.2, -0.2, 0.3, 0.3, -0.4], [2.0, 0.5, 0.3, 0.0, 0.2, 0.0]])
"""(N, 6) [cart_pos, cart_vel, pole1_angle, pole1_vel, pole2_angle, pole2_vel], all upright enough to run on."""


def spec_reward(obs: np.ndarray) -> np.ndarray:
    """The spec's reward of observations [cart_pos, pole1_angle, pole2_angle, cart_vel, pole1_vel, pole2_vel]."""
    x, a1, a2, _, w1, w2 = obs.T
    tip_pos = x - np.sin(a1) - np.sin(a1 + a2)
    tip_height = np.cos(a1) + np.cos(a1 + a2)
    return 1 - 0.001 * tip_pos**2 - 0.1 * (2 - tip_height) ** 2 - 1e-4 * w1**2 - 5e-4 * w2**2


def test_reward_is_the_specs_on_the_state_after_the_step(make):
    env = make(4, task_name=TASK)
    env.set_state(STATES.to(env.device))
    obs, reward, terminated, truncated, info = env.step(torch.zeros(4, 1, device=env.device))
    assert not (terminated.any() or truncated.any())
    expected = spec_reward(info["final_obs"].cpu().double().numpy())
    np.testing.assert_allclose(reward.cpu().numpy(), expected, rtol=1e-5, atol=1e-6)


def test_tip_of_the_spec_is_where_newton_puts_pole_twos_tip(make):
    """Newton's forward kinematics of each state: pole 2's tip (0.5 m along its body's Z from its centre on the stage)
    relative to pole 1's hinge, against the spec's tip_pos - cart_pos and tip_height."""
    env = make(4, task_name=TASK)
    obs = env.set_state(STATES.to(env.device)).cpu().double().numpy()
    model, state = env.scene.model, env.scene.state_0
    newton.eval_fk(model, state.joint_q, state.joint_qd, state)
    labels = [label.rsplit("/", 1)[-1] for label in model.body_label]
    body_q = state.body_q.numpy().reshape(4, -1, 7).astype(np.float64)
    pole1, pole2 = labels.index("pole1"), labels.index("pole2")

    def along_z(transform, distance):
        x, y, z, w = transform[3:]
        axis = np.array([2 * (x * z + w * y), 2 * (y * z - w * x), 1 - 2 * (x * x + y * y)])
        return transform[:3] + distance * axis

    for i in range(4):
        hinge = along_z(body_q[i, pole1], -0.5)
        tip = along_z(body_q[i, pole2], 0.5)
        x, a1, a2 = obs[i, :3]
        assert tip[1] - hinge[1] == pytest.approx(-math.sin(a1) - math.sin(a1 + a2), abs=1e-5)
        assert tip[2] - hinge[2] == pytest.approx(math.cos(a1) + math.cos(a1 + a2), abs=1e-5)
        assert hinge[1] == pytest.approx(x, abs=1e-5), "pole 1's hinge rides with the cart along the rail (Y)"


@pytest.mark.parametrize("state, reason", [
    ([0.0, 0.0, 0.5, 0.0, 0.5, 0.0], "tip_fell"),  # tip height cos 0.5 + cos 1 = 1.42 m < 1.5 m
    ([0.0, 0.0, 0.8, 0.0, -1.2, 0.0], "tip_fell"),  # 0.70 + 0.92 = 1.62 m at the start, falling
    ([3.2, 0.0, 0.0, 0.0, 0.0, 0.0], "cart_out_of_range"),
])
def test_ends_where_the_tip_falls_below_1_5_m_or_the_cart_leaves(state, reason, make):
    env = make(1, task_name=TASK)
    env.set_state(torch.tensor([state], device=env.device))
    for _ in range(30):
        _, _, terminated, _, info = env.step(torch.zeros(1, 1, device=env.device))
        if terminated.any():
            break
    assert terminated.all() and env.end_reasons[int(info["end_reason"][0])] == reason
    final = info["final_obs"].cpu().double().numpy()[0]
    height = math.cos(final[1]) + math.cos(final[1] + final[2])
    assert (height < 1.5) == (reason == "tip_fell") and (abs(final[0]) > 3.0) == (reason == "cart_out_of_range")


def test_reset_ranges_that_start_below_the_fall_height_are_refused(make):
    """Both poles leaning one way as far as the reset range goes: cos 0.5 + cos 1.0 = 1.42 m is below the 1.5 m at
    which an episode ends, cos 0.45 + cos 0.9 = 1.52 m is not; every reset of the wider accepted range starts above."""
    with pytest.raises(ConfigError, match=r"reset_pole_angle_rad=0.5 can start an episode with the tip 1.42 m high"):
        cartpole_warp.tasks.env_config(TASK, task={"reset_pole_angle_rad": 0.5})
    env = make(512, task_name=TASK, task={"reset_pole_angle_rad": 0.45})
    obs = env.reset()[0].cpu().double()
    heights = torch.cos(obs[:, 1]) + torch.cos(obs[:, 1] + obs[:, 2])
    assert heights.min() >= 1.5 and heights.min() < 1.6, "the range reaches near its limit"
