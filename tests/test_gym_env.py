"""gymnasium adapters: check_env, registration, and step-for-step agreement with the core env."""

import math
import warnings

import gymnasium as gym
import numpy as np
import pytest
import torch
from gymnasium.utils.env_checker import check_env
from gymnasium.vector import AutoresetMode

from cartpole_warp import CartpoleGymEnv, CartpoleVectorEnv, make_env
from cartpole_warp.kernels import END_REASONS
from cartpole_warp.wrappers.gymnasium import ENV_IDS

TUTORIAL_ID = "cartpole_warp/CartpoleTutorial-v0"
DEFAULT_ID = "cartpole_warp/Cartpole-v0"
SHORT_EPISODES = {"episode_length_s": 0.2}
"""12 env steps at 60 Hz: truncations within a short test."""


def random_actions(steps, num_envs, seed):
    return np.random.default_rng(seed).uniform(-1.0, 1.0, (steps, num_envs, 1)).astype(np.float32)


def test_single_env_passes_check_env():
    env = gym.make(TUTORIAL_ID)
    assert isinstance(env.unwrapped, CartpoleGymEnv)
    assert env.observation_space == gym.spaces.Box(-np.inf, np.inf, (4,), np.float32)
    assert env.action_space == gym.spaces.Box(-1.0, 1.0, (1,), np.float32)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        check_env(env.unwrapped)
    unexpected = [str(w.message) for w in caught if "infinity" not in str(w.message)]
    assert unexpected == []
    obs, info = env.reset(seed=3)
    assert obs.dtype == np.float32 and obs.shape == (4,) and info == {}


def test_registered_ids_build_their_presets():
    tutorial = gym.make(TUTORIAL_ID).unwrapped.core
    assert tutorial.num_envs == 1
    assert tutorial.env_dt == pytest.approx(1 / 60)
    assert tutorial.max_episode_length == 2**31 - 1
    default = gym.make(DEFAULT_ID, seed=4).unwrapped.core
    assert default.max_episode_length == 600
    assert default.cfg.seed == 4
    assert set(ENV_IDS) <= set(gym.registry)


def test_single_env_matches_batched_env_with_one_env():
    single = CartpoleGymEnv(preset="tutorial")
    core = make_env(num_envs=1, preset="tutorial")
    obs, _ = single.reset(seed=11)
    core_obs, _ = core.reset(seed=11)
    np.testing.assert_array_equal(obs, core_obs[0].numpy())
    episodes, ret, length = 0, 0.0, 0
    for action in random_actions(200, 1, seed=0):
        obs, reward, terminated, truncated, info = single.step(action[0])
        core_obs, core_reward, core_term, core_trunc, core_info = core.step(torch.from_numpy(action))
        ret, length = ret + reward, length + 1
        assert reward == float(core_reward[0])
        assert (terminated, truncated) == (bool(core_term[0]), bool(core_trunc[0]))
        assert isinstance(obs, np.ndarray) and obs.dtype == np.float32
        if terminated or truncated:
            np.testing.assert_array_equal(obs, core_info["final_obs"][0].numpy())
            assert abs(obs[0]) > 3.0 or abs(obs[2]) > math.pi / 2
            assert info["episode_length"] == length
            assert info["episode_return"] == pytest.approx(ret, rel=1e-5)
            assert info["end_reason"] in END_REASONS[1:3]
            obs, _ = single.reset()
            episodes, ret, length = episodes + 1, 0.0, 0
        else:
            assert info == {}
        np.testing.assert_array_equal(obs, core_obs[0].numpy())
    assert episodes >= 3


def test_seeded_reset_after_episode_end_is_deterministic():
    env = CartpoleGymEnv(preset="tutorial")
    first, _ = env.reset(seed=5)
    while not env.step(np.ones(1, np.float32))[2]:
        pass
    again, _ = env.reset(seed=5)
    np.testing.assert_array_equal(first, again)


def test_vector_env_matches_core_env_step_for_step():
    num_envs, seed = 32, 9
    venv = gym.make_vec(DEFAULT_ID, num_envs=num_envs, vectorization_mode="vector_entry_point", task=SHORT_EPISODES)
    assert isinstance(venv, CartpoleVectorEnv)
    assert venv.metadata["autoreset_mode"] == AutoresetMode.SAME_STEP
    assert venv.observation_space.shape == (num_envs, 4) and venv.action_space.shape == (num_envs, 1)
    core = make_env(num_envs=num_envs, preset="default", task=SHORT_EPISODES)
    obs, info = venv.reset(seed=seed)
    np.testing.assert_array_equal(obs, core.reset(seed=seed)[0].numpy())
    saw_terminated = saw_truncated = False
    for actions in random_actions(30, num_envs, seed=1):
        obs, reward, terminated, truncated, info = venv.step(actions)
        c_obs, c_reward, c_term, c_trunc, c_info = core.step(torch.from_numpy(actions))
        np.testing.assert_array_equal(obs, c_obs.numpy())
        np.testing.assert_array_equal(reward, c_reward.numpy())
        np.testing.assert_array_equal(terminated, c_term.numpy())
        np.testing.assert_array_equal(truncated, c_trunc.numpy())
        done = terminated | truncated
        saw_terminated |= terminated.any()
        saw_truncated |= truncated.any()
        if not done.any():
            assert info == {}
            continue
        np.testing.assert_array_equal(info["_final_obs"], done)
        np.testing.assert_array_equal(info["final_obs"][done], c_info["final_obs"].numpy()[done])
        np.testing.assert_array_equal(info["_final_info"], done)
        final = info["final_info"]
        for key in ("episode_return", "episode_length", "end_reason"):
            np.testing.assert_array_equal(final[f"_{key}"], done)
            np.testing.assert_array_equal(final[key][done], c_info[key].numpy()[done])
        assert (final["end_reason"][truncated] == END_REASONS.index("time_limit")).all()
    assert saw_terminated and saw_truncated


def test_wrong_action_count_is_a_clear_error():
    venv = CartpoleVectorEnv(num_envs=4, preset="default")
    venv.reset(seed=0)
    with pytest.raises(ValueError, match="expected 4 action value"):
        venv.step(np.zeros((3, 1), np.float32))
