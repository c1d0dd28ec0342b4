"""cart-two-pole-swingup and cart-three-pole-swingup against dm_control's ``two_poles`` and ``three_poles``: reward and
observations equal the independent numpy transcription in dmc_reference.py; resets follow dm_control's. The physics of
the chain stages: tests/test_physics.py."""

import math

import numpy as np
import pytest
import torch
from dmc_reference import chain_observations, chain_swingup_reward

CHAINS = [(2, "cart-two-pole-swingup"), (3, "cart-three-pole-swingup")]


def joint_states(n, num_poles, seed):
    """(q, qd), each (n, 1 + num_poles): cart within +-1.7 m, any hinge angle, velocities up to +-10 (a fifth of them
    within +-0.5 m, 0.1 rad and 1 rad/s of rest upright, where the reward's terms are largest)."""
    gen = torch.Generator().manual_seed(seed)
    q = (torch.rand((n, 1 + num_poles), generator=gen) * 2 - 1) * torch.tensor([1.7] + [2 * math.pi] * num_poles)
    qd = (torch.rand((n, 1 + num_poles), generator=gen) * 2 - 1) * 10.0
    q[: n // 5] *= torch.tensor([0.3] + [0.016] * num_poles)
    qd[: n // 5] *= 0.1
    return q, qd


def joints_of(obs: np.ndarray, num_poles: int) -> tuple[np.ndarray, np.ndarray]:
    """(q, qd) as ``joint_states`` gives them from observations: each pole's world angle from its cosine and sine,
    each hinge's angle the difference of its pole's and the one below's, in (-pi, pi]."""
    obs = obs.astype(np.float64)
    world = np.arctan2(obs[:, 2:2 * num_poles + 1:2], obs[:, 1:2 * num_poles:2])
    hinges = np.angle(np.exp(1j * np.diff(world, axis=1, prepend=0.0)))
    return np.concatenate([obs[:, :1], hinges], axis=1), obs[:, 2 * num_poles + 1:]


@pytest.mark.parametrize("num_poles, task_name", CHAINS)
def test_reward_and_observations_equal_dm_controls(num_poles, task_name, make, device):
    """Random states (set, then one step of random actions, a third beyond [-1, 1]): each set state's observation,
    and the step's reward from the state after it (read back from its observation) and the action."""
    n = 2048
    env = make(n, task_name=task_name)
    assert (env.num_obs, env.num_actions, env.joint_roles[1:]) == (3 * num_poles + 2, 1,
                                                                   ("pole", "pole2", "pole3")[:num_poles])
    q, qd = joint_states(n, num_poles, seed=num_poles)
    obs0 = env.set_state(torch.stack([q, qd], dim=2).reshape(n, -1).to(device)).cpu().numpy()
    np.testing.assert_allclose(obs0, chain_observations(q.numpy(), qd.numpy()), rtol=0, atol=2e-5)

    actions = (torch.rand((n, 1), generator=torch.Generator().manual_seed(5)) * 3 - 1.5).to(device)
    obs, reward, terminated, truncated, info = env.step(actions)
    assert not (terminated | truncated).any() and int(info["nonfinite_states"]) == 0
    obs = obs.cpu().numpy()
    after_q, after_qd = joints_of(obs, num_poles)
    np.testing.assert_allclose(obs[:, 1:2 * num_poles:2] ** 2 + obs[:, 2:2 * num_poles + 1:2] ** 2, 1.0, atol=1e-6)
    expected = chain_swingup_reward(after_q, after_qd, np.clip(actions.cpu().numpy(), -1, 1))
    np.testing.assert_allclose(reward.cpu().numpy(), expected, rtol=0, atol=1e-5)
    assert expected.min() < 0.01 and expected.max() > 0.6, "the sample spans the reward's range"


@pytest.mark.parametrize("num_poles, task_name", CHAINS)
def test_resets_are_dm_controls(num_poles, task_name, make):
    """dm_control's swing-up start on a chain: hinge_1 = pi + 0.01 N(0, 1), every further hinge 0.1 N(0, 1), the cart
    and every velocity 0.01 N(0, 1)."""
    env = make(4096, seed=3, task_name=task_name)
    q, qd = joints_of(env.reset()[0].cpu().numpy(), num_poles)
    q[:, 1] = np.remainder(q[:, 1], 2 * math.pi)
    centres = [0.0, math.pi] + [0.0] * (num_poles - 1)
    spreads = [0.01, 0.01] + [0.1] * (num_poles - 1)
    for j in range(1 + num_poles):
        assert q[:, j].mean() == pytest.approx(centres[j], abs=4 * spreads[j] / 64), f"joint {j}"
        assert q[:, j].std() == pytest.approx(spreads[j], rel=0.05), f"joint {j}"
        assert qd[:, j].std() == pytest.approx(0.01, rel=0.05), f"joint {j} velocity"
