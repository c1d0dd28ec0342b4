"""cartpole-swingup against dm_control's ``cartpole.swingup``: reward and observations equal the independent numpy
transcription in dmc_reference.py; resets hang the pole down with dm_control's noise; episodes end only at the 10 s
time limit; the slider's +-1.8 m limits keep the cart on its rail."""

import math

import numpy as np
import pytest
import torch
from dmc_reference import swingup_observations, swingup_reward

SWINGUP = "cartpole-swingup"
CART_LIMIT_M = 1.8
"""dm_control/suite/cartpole.xml: slider range -1.8 1.8 (the stage's cartJoint limits)."""
PENETRATION_M = 0.1
"""How far past its limit the cart may go (the solvers' limits are stiff springs, not hard constraints)."""


def random_states(n, seed):
    """(n, 4) [cart_pos, cart_vel, pole_angle, pole_vel]: cart within +-1.7 m, any pole angle (two turns either way),
    velocities up to +-10 m/s and rad/s."""
    gen = torch.Generator().manual_seed(seed)
    scale = torch.tensor([1.7, 10.0, 2 * math.pi, 10.0])
    return (torch.rand((n, 4), generator=gen) * 2 - 1) * scale


def states_of(obs: np.ndarray) -> np.ndarray:
    """(N, 4) [cart_pos, cart_vel, pole_angle, pole_vel] from swing-up observations (N, 5); the angle in (-pi, pi]."""
    return np.stack([obs[:, 0], obs[:, 3], np.arctan2(obs[:, 2], obs[:, 1]), obs[:, 4]], axis=1)


def test_reward_and_observations_equal_dm_controls(make, device):
    """Random states and actions (a third beyond [-1, 1]): the observation of each set state, and the reward of the
    step, computed by the reference from the state after the step (read back from its observation) and the action."""
    n = 2048
    env = make(n, task_name=SWINGUP)
    assert env.num_obs == 5 and env.num_actions == 1
    states = random_states(n, seed=4)
    obs0 = env.set_state(states.to(device)).cpu().numpy()
    np.testing.assert_allclose(obs0, swingup_observations(states.numpy()), rtol=0, atol=1e-5)

    actions = (torch.rand((n, 1), generator=torch.Generator().manual_seed(5)) * 3 - 1.5).to(device)
    obs, reward, terminated, truncated, info = env.step(actions)
    assert not (terminated | truncated).any(), "no episode ends: obs is the state after the step"
    assert int(info["nonfinite_states"]) == 0
    obs, reward, actions = obs.cpu().numpy(), reward.cpu().numpy(), actions.cpu().numpy()[:, 0]
    after = states_of(obs)
    np.testing.assert_allclose(obs[:, 1] ** 2 + obs[:, 2] ** 2, 1.0, atol=1e-6)
    np.testing.assert_allclose(obs, swingup_observations(after), rtol=0, atol=1e-6)
    clipped = np.clip(actions, -1.0, 1.0)
    expected = swingup_reward(after, clipped)
    np.testing.assert_allclose(reward, expected, rtol=0, atol=1e-5)
    # dm_control rewards the raw ctrl (MuJoCo clamps it only in the force): the same, since small_control is 0 at
    # and beyond the margin 1
    np.testing.assert_array_equal(swingup_reward(after, actions), expected)

    # the sample covers the reward's terms: both ends of its range, clipped actions, the cart near its limits
    assert reward.min() < 0.01 and reward.max() > 0.6
    assert 0.25 < (np.abs(actions) > 1).mean() < 0.45
    assert np.abs(after[:, 0]).max() > 1.6 and np.abs(after[:, 3]).max() > 9.0


def test_resets_start_hanging_down_with_dm_controls_noise(make):
    """dm_control's swing-up start: pole_angle = pi + 0.01 N(0, 1); cart_pos, cart_vel, pole_vel = 0.01 N(0, 1)."""
    env = make(4096, seed=7, task_name=SWINGUP)
    obs = torch.cat([env.reset()[0].cpu() for _ in range(2)]).double()
    angle = torch.remainder(torch.atan2(obs[:, 2], obs[:, 1]), 2 * math.pi)
    samples = {"cart_pos": obs[:, 0], "pole_angle": angle, "cart_vel": obs[:, 3], "pole_vel": obs[:, 4]}
    for name, values in samples.items():
        centre = math.pi if name == "pole_angle" else 0.0
        assert values.mean().item() == pytest.approx(centre, abs=5e-4), name
        assert values.std().item() == pytest.approx(0.01, rel=0.05), name
        within_one_sigma = ((values - centre).abs() < 0.01).double().mean().item()
        assert within_one_sigma == pytest.approx(0.6827, abs=0.02), f"{name}: not Gaussian"
    assert len(torch.unique(obs[:, 0])) > 8000, "every env draws its own start"


def test_episodes_end_only_by_the_time_limit(make, device):
    """No termination whatever the actions: every episode runs 500 env steps (10 s at 50 Hz) and is truncated."""
    n = 16
    env = make(n, task_name=SWINGUP, preset=None)
    assert env.env_dt == pytest.approx(0.02) and env.max_episode_length == 500
    assert env.end_reasons == ("running", "time_limit", "nonfinite_state", "diverged_state")
    env.reset()
    gen = torch.Generator().manual_seed(1)
    total = torch.zeros(n, dtype=torch.float64)
    for step in range(1, 501):
        actions = torch.where(torch.rand((n, 1), generator=gen) < 0.5, -1.0, 1.0).to(device)
        _, reward, terminated, truncated, info = env.step(actions)
        total += reward.cpu().double()
        assert not terminated.any(), f"step {step}"
        assert torch.equal(truncated.cpu(), torch.full((n,), step == 500)), f"step {step}"
    assert (info["end_reason"] == env.end_reasons.index("time_limit")).all()
    assert (info["episode_length"] == 500).all()
    torch.testing.assert_close(info["episode_return"].cpu().double(), total, rtol=1e-4, atol=1e-3)
    assert ((reward >= 0) & (reward <= 1)).all()


@pytest.mark.parametrize("solver", ["featherstone", "mujoco"])
def test_the_slider_limits_keep_the_cart_on_its_rail(solver, make, device):
    """10 s of full-force actions (10 N): pushed one way throughout, or bang-bang switching at random; the cart reaches
    its +-1.8 m limits and stays within them, up to a small penetration (Featherstone reads the stage's
    newton:limitStiffness / limitDamping, SolverMuJoCo its mjc:solreflimit; with Newton's default limit the cart
    bounced back and reached 1.91 m and 2.72 m)."""
    n = 48
    env = make(n, task_name=SWINGUP, sim={"solver": solver})
    env.reset()
    gen = torch.Generator().manual_seed(2)
    signs = torch.cat([torch.ones(16), -torch.ones(16), torch.where(torch.rand(16, generator=gen) < 0.5, -1.0, 1.0)])
    reach = torch.zeros(n)
    for step in range(1, env.max_episode_length + 1):
        switch = torch.rand(n, generator=gen) < 0.05
        switch[:32] = False
        signs = torch.where(switch, -signs, signs)
        obs, _, terminated, truncated, info = env.step(signs.unsqueeze(1).to(device))
        assert not terminated.any()
        assert torch.equal(truncated.cpu(), torch.full((n,), step == env.max_episode_length))
        reach = torch.maximum(reach, info["final_obs"][:, 0].abs().cpu())
    assert int(info["nonfinite_states"]) == 0
    assert reach.max() <= CART_LIMIT_M + PENETRATION_M, f"the cart went {reach.max():.3f} m from the centre"
    assert (reach[:32] > CART_LIMIT_M - PENETRATION_M).all(), "pushed one way, the cart reaches its limit"
