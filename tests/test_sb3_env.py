"""Stable-Baselines3 adapter, for every registered task: the VecEnv contract, sb3's check_env on the single env, and
a short PPO run."""

import numpy as np
import pytest
import torch
from conftest import SB3_EXTRA, optional_module

import cartpole_warp
from cartpole_warp import TaskGymEnv
from cartpole_warp.wrappers.gymnasium import env_ids

PPO = optional_module("stable_baselines3", SB3_EXTRA).PPO
sb3_check_env = optional_module("stable_baselines3.common.env_checker", SB3_EXTRA).check_env
Monitor = optional_module("stable_baselines3.common.monitor", SB3_EXTRA).Monitor
VecEnv = optional_module("stable_baselines3.common.vec_env", SB3_EXTRA).VecEnv
TaskSb3VecEnv = optional_module("cartpole_warp.wrappers.sb3", SB3_EXTRA).TaskSb3VecEnv

TASKS = cartpole_warp.tasks.names()
SHORT_EPISODES = {"episode_length_s": 0.2}
"""10-12 env steps: truncations within a short test."""


def make_env(task_name, num_envs, **overrides):
    """Task ``task_name``'s env on the CPU; ``overrides`` as for ``tasks.make`` (``task={...}``: its settings)."""
    return cartpole_warp.tasks.make(task_name, num_envs=num_envs, preset="default", **overrides)


@pytest.mark.parametrize("env_id", env_ids())
def test_single_gym_env_passes_sb3_check_env(env_id):
    task, preset = env_ids()[env_id]
    env = TaskGymEnv(task_name=task, preset=preset)
    sb3_check_env(env, warn=False)
    assert env.observation_space.shape == env.env.obs_shape


@pytest.mark.parametrize("task", TASKS)
def test_vec_env_steps_like_the_core_env_with_sb3_infos(task):
    num_envs, seed = 16, 21
    venv = TaskSb3VecEnv(make_env(task, num_envs, task=SHORT_EPISODES))
    core = make_env(task, num_envs, task=SHORT_EPISODES)
    assert isinstance(venv, VecEnv) and venv.num_envs == num_envs
    assert venv.observation_space.shape == core.obs_shape and venv.action_space.shape == (1,)
    venv.seed(seed)
    obs = venv.reset()
    assert obs.dtype == venv.observation_space.dtype and obs.shape == (num_envs, *core.obs_shape)
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
    assert saw_truncated
    assert saw_terminated <= bool(core.task_ends), "only a task with failures terminates"
    if core.task_ends and type(core).__name__ == "CartpoleBalanceEnv":
        assert saw_terminated, "random 400 N pushes end balance episodes early (the double pole's 40 N do not)"
    assert venv.episode_count >= num_envs * 2


@pytest.mark.parametrize("task", TASKS)
def test_vec_env_seed_reset_and_errors(task):
    venv = TaskSb3VecEnv(make_env(task, 4))
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


@pytest.mark.parametrize("task", TASKS)
def test_vec_env_attributes_and_methods_act_on_the_shared_env(task):
    venv = TaskSb3VecEnv(make_env(task, 4))
    limit = cartpole_warp.tasks.env_config(task).max_episode_length
    assert limit == {"cartpole-balance": 600, "cartpole-swingup": 500}.get(task, limit)
    venv.reset()
    assert venv.get_attr("max_episode_length") == [limit] * 4
    assert venv.get_attr("num_envs", indices=[1, 2]) == [4, 4]
    assert venv.has_attr("env_dt") and not venv.has_attr("no_such_attribute")
    venv.set_attr("episode_length_buf", torch.full((4,), limit - 1, dtype=torch.int32))
    _, _, dones, infos = venv.step(np.zeros((4, 1), np.float32))
    assert dones.all() and all(info["TimeLimit.truncated"] for info in infos)
    states = torch.full((4, 2 * len(venv.env.joint_roles)), 0.1)
    (obs,) = venv.env_method("set_state", states, indices=[0])
    reference = make_env(task, 4)
    assert torch.equal(obs, reference.set_state(states)) and torch.equal(obs, venv.env.get_observations())
    assert venv.env_is_wrapped(Monitor) == [False] * 4


@pytest.mark.parametrize("task", TASKS)
def test_short_ppo_run_on_vec_env(task):
    """SB3's PPO trains two rollouts of 64 steps of 16 envs (two 1 s episodes each): its MlpPolicy on the state, its
    CnnPolicy (NatureCNN) on camera frames (uint8 colour normalised by SB3; depth in metres as it is), at 36x36, the
    smallest frames NatureCNN takes."""
    venv = TaskSb3VecEnv(make_env(task, 16, task={"episode_length_s": 1.0}, camera={"width_px": 36, "height_px": 36}))
    image = venv.env.cfg.camera.image
    policy = "MlpPolicy" if image == "none" else "CnnPolicy"
    model = PPO(policy, venv, n_steps=64, batch_size=256, n_epochs=2, seed=0, device="cpu",
                policy_kwargs={"normalize_images": image != "depth"})
    model.learn(total_timesteps=2048)
    assert model.num_timesteps >= 2048
    assert len(model.ep_info_buffer) > 0
    assert all(e["l"] > 0 for e in model.ep_info_buffer)
    obs = venv.reset()
    actions, _ = model.predict(obs, deterministic=True)
    assert actions.shape == (16, 1)


def test_without_the_sb3_extra_the_import_says_what_to_install(monkeypatch):
    import importlib
    import sys

    monkeypatch.setitem(sys.modules, "stable_baselines3.common.vec_env", None)  # as if not installed
    monkeypatch.delitem(sys.modules, "cartpole_warp.wrappers.sb3")
    with pytest.raises(ModuleNotFoundError, match=r"needs the sb3 extra .*pip install 'cartpole_warp\[sb3\]'"):
        importlib.import_module("cartpole_warp.wrappers.sb3")
