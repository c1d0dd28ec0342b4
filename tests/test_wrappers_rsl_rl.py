"""The rsl-rl adapter (``wrappers/rsl_rl.py``) against rsl-rl's ``VecEnv`` contract, for every task."""


import pytest
import torch
from tensordict import TensorDict

from cartpole_warp import tasks
from cartpole_warp.wrappers.rsl_rl import RslRlVecEnv


@pytest.mark.parametrize("task", tasks.names())
def test_adapter_follows_the_rsl_rl_vecenv_contract(task):
    env = RslRlVecEnv(tasks.make(task, num_envs=8, seed=1, sim={"physics_dt": 1 / 120, "decimation": 2},
                                 task={"episode_length_s": 0.1}))
    shape = env.env.obs_shape  # (num_obs,), or camera frames
    assert (env.num_envs, env.num_actions, env.max_episode_length) == (8, 1, 6)
    obs = env.get_observations()
    assert isinstance(obs, TensorDict) and obs["policy"].shape == (8, *shape) and obs.batch_size == torch.Size([8])
    env.episode_length_buf = torch.full((8,), 4, dtype=torch.int32)
    assert env.env.episode_length_buf.tolist() == [4] * 8
    obs, rewards, dones, extras = env.step(torch.zeros(8, 1))
    assert rewards.shape == (8,) and dones.shape == (8,) and dones.dtype == torch.int64
    assert not extras["time_outs"].any()
    obs, rewards, dones, extras = env.step(torch.zeros(8, 1))
    assert dones.tolist() == [1] * 8 and extras["time_outs"].all(), "counters set to 4 reach the 6-step limit"
    assert extras["episode_length"].tolist() == [2] * 8, "the reported length is the steps really run"
    assert extras["final_obs"].shape == (8, *shape)
    assert obs["policy"].shape == (8, *shape) and env.episode_length_buf.tolist() == [0] * 8
