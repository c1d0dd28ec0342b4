"""Stable-Baselines3 adapter: the VecEnv contract and a short PPO run."""

import numpy as np
import pytest
import torch
from stable_baselines3 import PPO
from stable_baselines3.common.env_checker import check_env as sb3_check_env
from stable_baselines3.common.monitor import Monitor
from stable_baselines3.common.vec_env import VecEnv

from cartpole_warp import CartpoleGymEnv, make_env
from cartpole_warp.wrappers.sb3 import CartpoleSb3VecEnv

SHORT_EPISODES = {"episode_length_s": 0.2}
"""12 env steps at 60 Hz: truncations within a short test."""


def test_single_gym_env_passes_sb3_check_env():
    sb3_check_env(CartpoleGymEnv(preset="tutorial"), warn=False)


def test_vec_env_steps_like_the_core_env_with_sb3_infos():
    num_envs, seed = 16, 21
    venv = CartpoleSb3VecEnv(make_env(num_envs=num_envs, preset="default", task=SHORT_EPISODES))
    core = make_env(num_envs=num_envs, preset="default", task=SHORT_EPISODES)
    assert isinstance(venv, VecEnv) and venv.num_envs == num_envs
    venv.seed(seed)
    obs = venv.reset()
    assert obs.dtype == np.float32 and obs.shape == (num_envs, 4)
    np.testing.assert_array_equal(obs, core.reset(seed=seed)[0].numpy())
    returns, lengths = np.zeros(num_envs), np.zeros(num_envs, int)
    saw_terminated = saw_truncated = False
    for actions in np.random.default_rng(2).uniform(-1, 1, (30, num_envs, 1)).astype(np.float32):
        venv.step_async(actions)
        obs, rewards, dones, infos = venv.step_wait()
        c_obs, c_reward, c_term, c_trunc, c_info = core.step(torch.from_numpy(actions))
        np.testing.assert_array_equal(obs, c_obs.numpy())
        np.testing.assert_array_equal(rewards, c_reward.numpy())
        np.testing.assert_array_equal(dones, (c_term | c_trunc).numpy())
        assert isinstance(infos, list) and len(infos) == num_envs
        returns += rewards
        lengths += 1
        for i in range(num_envs):
            if not dones[i]:
                assert infos[i] == {}
                continue
            np.testing.assert_array_equal(infos[i]["terminal_observation"], c_info["final_obs"][i].numpy())
            assert infos[i]["TimeLimit.truncated"] == bool(c_trunc[i])
            assert infos[i]["episode"]["l"] == lengths[i]
            assert infos[i]["episode"]["r"] == pytest.approx(returns[i], rel=1e-5)
            saw_truncated |= bool(c_trunc[i])
            saw_terminated |= bool(c_term[i])
        returns[dones], lengths[dones] = 0.0, 0
    assert saw_terminated and saw_truncated
    assert venv.episode_count > 0


def test_vec_env_seed_reset_and_errors():
    venv = CartpoleSb3VecEnv(make_env(num_envs=4, preset="default"))
    venv.seed(3)
    first = venv.reset()
    unseeded = venv.reset()
    venv.seed(3)
    np.testing.assert_array_equal(venv.reset(), first)
    assert not np.array_equal(unseeded, first)
    with pytest.raises(RuntimeError, match="step_async"):
        venv.step_wait()
    with pytest.raises(ValueError, match="expected 4 action value"):
        venv.step(np.zeros((2, 1), np.float32))


def test_vec_env_attributes_and_methods_act_on_the_shared_env():
    venv = CartpoleSb3VecEnv(make_env(num_envs=4, preset="default"))
    venv.reset()
    assert venv.get_attr("max_episode_length") == [600] * 4
    assert venv.get_attr("num_envs", indices=[1, 2]) == [4, 4]
    assert venv.has_attr("env_dt") and not venv.has_attr("no_such_attribute")
    venv.set_attr("episode_length_buf", torch.full((4,), 599, dtype=torch.int32))
    _, _, dones, infos = venv.step(np.zeros((4, 1), np.float32))
    assert dones.all() and all(info["TimeLimit.truncated"] for info in infos)
    states = torch.zeros(4, 4)
    (obs,) = venv.env_method("set_state", states, indices=[0])
    assert torch.equal(obs, states)
    assert venv.env_is_wrapped(Monitor) == [False] * 4


def test_short_ppo_run_on_vec_env():
    venv = CartpoleSb3VecEnv(make_env(num_envs=16, preset="default"))
    model = PPO("MlpPolicy", venv, n_steps=64, batch_size=256, n_epochs=2, seed=0, device="cpu")
    model.learn(total_timesteps=4096)
    assert model.num_timesteps >= 4096
    assert len(model.ep_info_buffer) > 0
    assert all(e["l"] > 0 for e in model.ep_info_buffer)
