"""cartpole-balance-sparse: dm_control's sparse reward (the independent transcription in dmc_reference.py) on the
balance's dynamics, ends and resets."""

import numpy as np
import torch
from dmc_reference import on_the_edge, sparse_reward


def test_reward_is_dm_controls_sparse_reward_and_the_ends_the_balances(make, device):
    """Random states around the band and beyond the balance's limits, one step of random actions: the reward from the
    state after the step (its final observation) is dm_control's sparse reward; terminations equal the balance's on the
    same states and actions, and earn 0."""
    n = 4096
    gen = torch.Generator().manual_seed(0)
    states = (torch.rand((n, 4), generator=gen) * 2 - 1) * torch.tensor([0.5, 0.3, 0.2, 0.3])
    states[: n // 8] *= torch.tensor([8.0, 1.0, 10.0, 1.0])  # some beyond 3 m or pi / 2: the balance's failures
    actions = (torch.rand((n, 1), generator=gen) * 2 - 1).to(device)
    sparse, balance = make(n, task_name="cartpole-balance-sparse"), make(n, task_name="cartpole-balance")
    results = []
    for env in (sparse, balance):
        env.set_state(states.to(device))
        results.append(env.step(actions))
    _, reward, terminated, truncated, info = results[0]
    after = info["final_obs"].cpu().numpy()
    expected = sparse_reward(after[:, [0, 2]])
    clear = ~on_the_edge(after[:, 0], np.cos(after[:, 2]))
    np.testing.assert_array_equal(reward.cpu().numpy()[clear], expected[clear])
    assert 0.2 < expected.mean() < 0.8, "the sample spans the band's edges"
    assert torch.equal(terminated, results[1][2]) and terminated.sum() > 100
    assert (reward[terminated] == 0).all()
