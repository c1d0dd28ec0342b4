"""cartpole-swingup-sparse against dm_control's ``swingup_sparse``: the sparse reward equals the independent
transcription in dmc_reference.py; dynamics, resets and time limit are the swing-up's (tests/test_swingup.py)."""

import numpy as np
import torch
from dmc_reference import on_the_edge, sparse_reward


def test_reward_is_dm_controls_sparse_reward(make, device):
    """Random states, two thirds near the band: the step's reward from the state after it (read back from its
    observation, [cart_pos, cos, sin, cart_vel, pole_vel]) is dm_control's sparse reward, and nothing ends."""
    n = 4096
    gen = torch.Generator().manual_seed(1)
    states = (torch.rand((n, 4), generator=gen) * 2 - 1) * torch.tensor([1.7, 1.0, 3.2, 1.0])
    states[: 2 * n // 3] *= torch.tensor([0.25, 0.3, 0.04, 0.3])
    env = make(n, task_name="cartpole-swingup-sparse")
    env.set_state(states.to(device))
    obs, reward, terminated, truncated, _ = env.step((torch.rand((n, 1), generator=gen) * 2 - 1).to(device))
    obs = obs.cpu().numpy().astype(np.float64)
    expected = sparse_reward(np.stack([obs[:, 0], np.arctan2(obs[:, 2], obs[:, 1])], axis=1))
    clear = ~on_the_edge(obs[:, 0], obs[:, 1])
    np.testing.assert_array_equal(reward.cpu().numpy()[clear], expected[clear])
    assert 0.2 < expected.mean() < 0.8, "the sample spans the band's edges"
    assert not (terminated | truncated).any()
