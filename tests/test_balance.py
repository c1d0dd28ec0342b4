"""cartpole-balance (``tasks/balance.py``): tutorial parity of its reward, termination and reset ranges, checked
against the tutorial's own formulas; its state and failures."""

import math

import numpy as np
import torch

# From the tutorial (cartpole_task.py): _reset_dist = 3.0, _max_push_effort = 400.0
RESET_DIST = 3.0
BALANCE = "cartpole-balance"


def tutorial_reward(obs):
    """``calculate_metrics`` of the tutorial, verbatim but batched."""
    cart_pos, cart_vel, pole_angle, pole_vel = obs[:, 0], obs[:, 1], obs[:, 2], obs[:, 3]
    reward = 1.0 - pole_angle * pole_angle - 0.01 * torch.abs(cart_vel) - 0.005 * torch.abs(pole_vel)
    reward = torch.where(torch.abs(cart_pos) > RESET_DIST, torch.ones_like(reward) * -2.0, reward)
    reward = torch.where(torch.abs(pole_angle) > np.pi / 2, torch.ones_like(reward) * -2.0, reward)
    return reward


def tutorial_is_done(obs):
    """``is_done`` of the tutorial, batched."""
    cart_pos, pole_pos = obs[:, 0], obs[:, 2]
    resets = torch.where(torch.abs(cart_pos) > RESET_DIST, 1, 0)
    resets = torch.where(torch.abs(pole_pos) > math.pi / 2, 1, resets)
    return resets.bool()


def sample_states(num_envs, seed):
    """States spread over and beyond the termination bounds."""
    gen = torch.Generator().manual_seed(seed)
    scale = torch.tensor([4.0, 3.0, 2.2, 6.0])
    return (torch.rand((num_envs, 4), generator=gen) * 2 - 1) * scale


def test_reward_and_termination_equal_the_tutorial_formulas(make, random_actions):
    n = 4096
    for preset in ("default", "tutorial"):
        env = make(n, preset=preset, task_name=BALANCE)
        env.set_state(sample_states(n, seed=1).to(env.device))
        _, reward, terminated, truncated, info = env.step(random_actions(n, 1)[0])
        final = info["final_obs"].cpu()
        expected_done = tutorial_is_done(final)
        assert 0.2 < expected_done.float().mean() < 0.9, "the sample must cover both outcomes"
        torch.testing.assert_close(reward.cpu(), tutorial_reward(final), rtol=1e-5, atol=1e-5)
        assert torch.equal(terminated.cpu(), expected_done)
        assert not truncated.any()
        # the end reason names the tutorial's first failing check: the cart, then the pole
        cart_out = final[:, 0].abs() > RESET_DIST
        expected = torch.where(cart_out, env.end_reasons.index("cart_out_of_range"),
                               torch.where(expected_done, env.end_reasons.index("pole_fell"), 0))
        assert torch.equal(info["end_reason"].cpu(), expected.int())
        assert 0 < int(cart_out.sum()) < int(expected_done.sum()), "both failures occur"


def test_observation_order_matches_the_physics(make):
    """cart_vel is the derivative of cart_pos and pole_vel that of pole_angle (observation order)."""
    env = make(8, task_name=BALANCE, task={"reset_dist_m": 100.0, "max_pole_angle_rad": 100.0})
    states = torch.tensor([[0.1 * i, 0.5, 0.05 * i, -0.3] for i in range(8)])
    env.set_state(states.to(env.device))
    obs1, *_ = env.step(torch.zeros(8, 1, device=env.device))
    obs2, *_ = env.step(torch.zeros(8, 1, device=env.device))
    dt = env.env_dt
    torch.testing.assert_close((obs2[:, 0] - obs1[:, 0]) / dt, (obs1[:, 1] + obs2[:, 1]) / 2, atol=0.02, rtol=0.02)
    torch.testing.assert_close((obs2[:, 2] - obs1[:, 2]) / dt, (obs1[:, 3] + obs2[:, 3]) / 2, atol=0.05, rtol=0.05)


def test_resets_fall_in_the_tutorial_ranges_and_cover_them(make):
    env = make(4096, seed=3, task_name=BALANCE)
    samples = torch.cat([env.reset()[0].cpu() for _ in range(4)])
    # tutorial reset(): cart 1.0*(1-2u), pole 0.125*pi*(1-2u), cart_vel 0.5*(1-2u), pole_vel 0.25*pi*(1-2u)
    bounds = torch.tensor([1.0, 0.5, 0.125 * math.pi, 0.25 * math.pi])
    assert (samples.abs() <= bounds).all()
    assert (samples.max(dim=0).values > 0.99 * bounds).all()
    assert (samples.min(dim=0).values < -0.99 * bounds).all()
    for k in range(4):
        hist = torch.histc(samples[:, k], bins=10, min=-bounds[k].item(), max=bounds[k].item())
        assert (hist > 0.8 * len(samples) / 10).all(), f"component {k} is not uniform: {hist}"


def test_set_state_of_the_balance_task_is_its_observation(make, device):
    """Balance observes the state itself: [cart_pos, cart_vel, pole_angle, pole_vel]."""
    env = make(4)
    states = torch.arange(16, dtype=torch.float32, device=device).reshape(4, 4) / 100
    assert torch.equal(env.set_state(states), states)


def test_balance_states_beyond_the_limits_end_for_that_reason(make, device):
    """Balance only (the swing-up has no failures): a state beyond the limits ends with the failure reward and the
    failure's reason, also when the physics then turns non-finite (reward 0); other envs run on."""
    env = make(5)
    assert env.end_reasons == ("running", "time_limit", "nonfinite_state", "diverged_state", "cart_out_of_range",
                               "pole_fell")
    states = torch.tensor([[3.5, 0.0, 0.0, 0.0], [-3.5, 0.0, 0.3, 0.0], [0.0, 0.0, 3.0, 0.0], [3.5, 0.0, 0.0, 0.0],
                           [0.2, 0.1, 0.05, -0.1]], device=device)
    start = env.set_state(states)
    qd = env.scene.state_0.joint_qd
    values = qd.numpy()
    values[3 * env.scene.dofs_per_env + env.scene.role_dofs[1]] = math.nan
    qd.assign(values)
    _, reward, terminated, truncated, info = env.step(torch.zeros(5, 1, device=device))
    reasons = [env.end_reasons[code] for code in info["end_reason"].tolist()]
    assert reasons == ["cart_out_of_range", "cart_out_of_range", "pole_fell", "cart_out_of_range", "running"]
    assert terminated.tolist() == [True] * 4 + [False] and not truncated.any()
    assert reward[:3].tolist() == [-2.0] * 3, "the failure reward"
    assert float(reward[3]) == 0.0 and int(info["nonfinite_states"]) == 1, "a non-finite state is rewarded 0"
    assert 0.0 < float(reward[4]) <= 1.0
    assert torch.isfinite(info["final_obs"]).all() and torch.equal(info["final_obs"][3], start[3])
    assert (env.get_observations()[:4].abs() <= torch.tensor([1.0, 0.5, math.pi / 8, math.pi / 4], device=device)).all()
