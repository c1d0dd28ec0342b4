"""gymnasium adapters, for every registered task id: check_env, registration, and step-for-step agreement with the
core env."""

import warnings

import gymnasium as gym
import numpy as np
import pytest
import torch
from gymnasium.utils.env_checker import check_env
from gymnasium.vector import AutoresetMode

import cartpole_warp
from cartpole_warp import TaskGymEnv, TaskVectorEnv
from cartpole_warp.wrappers.gymnasium import env_ids

TUTORIAL_ID = "cartpole_warp/CartpoleTutorial-v0"
DEFAULT_ID = "cartpole_warp/Cartpole-v0"
SWINGUP_ID = "cartpole_warp/CartpoleSwingup-v0"
DOUBLE_POLE_ID = "cartpole_warp/CartDoublePole-v0"
IDS = env_ids()
"""Every registered task's ids: id -> (task name, preset)."""
SHORT_EPISODES = {"episode_length_s": 0.2}
"""10-12 env steps: truncations within a short test."""


def random_actions(steps, num_envs, seed):
    return np.random.default_rng(seed).uniform(-1.0, 1.0, (steps, num_envs, 1)).astype(np.float32)


def core_env(env_id, num_envs, **overrides):
    task, preset = IDS[env_id]
    return cartpole_warp.tasks.make(task, num_envs=num_envs, preset=preset, **overrides)


def test_every_task_has_ids_and_they_are_registered():
    assert IDS == {DEFAULT_ID: ("cartpole-balance", None), TUTORIAL_ID: ("cartpole-balance", "tutorial"),
                   SWINGUP_ID: ("cartpole-swingup", None), DOUBLE_POLE_ID: ("cart-double-pole-balance", None),
                   "cartpole_warp/CartpoleBalanceSparse-v0": ("cartpole-balance-sparse", None),
                   "cartpole_warp/CartpoleSwingupSparse-v0": ("cartpole-swingup-sparse", None),
                   "cartpole_warp/CartTwoPoleSwingup-v0": ("cart-two-pole-swingup", None),
                   "cartpole_warp/CartThreePoleSwingup-v0": ("cart-three-pole-swingup", None),
                   "cartpole_warp/CartpoleBalanceRGB-v0": ("cartpole-balance-rgb", None),
                   "cartpole_warp/CartpoleBalanceDepth-v0": ("cartpole-balance-depth", None),
                   "cartpole_warp/CartpoleSwingupRGB-v0": ("cartpole-swingup-rgb", None),
                   "cartpole_warp/CartDoublePoleRGB-v0": ("cart-double-pole-balance-rgb", None)}
    assert {task for task, _ in IDS.values()} == set(cartpole_warp.tasks.names())
    assert set(IDS) <= set(gym.registry)


@pytest.mark.parametrize("env_id", IDS)
def test_single_env_passes_check_env(env_id):
    env = gym.make(env_id)
    task, _ = IDS[env_id]
    num_obs = cartpole_warp.tasks.get(task).env_class.num_obs
    assert isinstance(env.unwrapped, TaskGymEnv)
    assert isinstance(env.unwrapped.env, cartpole_warp.tasks.get(task).env_class)
    camera = env.unwrapped.env.cfg.camera
    frames = (camera.frame_stack, camera.height_px, camera.width_px)
    assert env.observation_space == {
        "none": gym.spaces.Box(-np.inf, np.inf, (num_obs,), np.float32),
        "rgb": gym.spaces.Box(0, 255, (3 * frames[0], *frames[1:]), np.uint8),
        "depth": gym.spaces.Box(0.0, np.inf, frames, np.float32)}[camera.image]
    assert env.action_space == gym.spaces.Box(-1.0, 1.0, (1,), np.float32)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        check_env(env.unwrapped)
    unexpected = [str(w.message) for w in caught if "infinity" not in str(w.message)]
    assert unexpected == []
    obs, info = env.reset(seed=3)
    assert obs.dtype == env.observation_space.dtype and obs.shape == env.observation_space.shape and info == {}
    obs, reward, terminated, truncated, info = env.step(env.action_space.sample())
    assert obs.shape == env.observation_space.shape and isinstance(reward, float)


def test_registered_ids_build_their_presets():
    tutorial = gym.make(TUTORIAL_ID).unwrapped.env
    assert tutorial.num_envs == 1
    assert tutorial.env_dt == pytest.approx(1 / 60)
    assert tutorial.max_episode_length == 2**31 - 1
    default = gym.make(DEFAULT_ID, seed=4).unwrapped.env
    assert default.max_episode_length == 600
    assert default.cfg.seed == 4
    swingup = gym.make(SWINGUP_ID, seed=2).unwrapped.env
    assert isinstance(swingup, cartpole_warp.tasks.get("cartpole-swingup").env_class)
    assert swingup.num_envs == 1 and swingup.num_obs == 5 and swingup.cfg.seed == 2
    assert swingup.env_dt == pytest.approx(0.02) and swingup.max_episode_length == 500


@pytest.mark.parametrize("env_id", IDS)
def test_single_env_matches_batched_env_with_one_env(env_id):
    """A short time limit makes every task end episodes (the swing-up only ever truncates)."""
    task, preset = IDS[env_id]
    single = TaskGymEnv(task_name=task, preset=preset, task=SHORT_EPISODES)
    core = core_env(env_id, 1, task=SHORT_EPISODES)
    obs, _ = single.reset(seed=11)
    core_obs, _ = core.reset(seed=11)
    np.testing.assert_array_equal(obs, core_obs[0].numpy())
    episodes, ret, length = 0, 0.0, 0
    for action in random_actions(100, 1, seed=0):
        obs, reward, terminated, truncated, info = single.step(action[0])
        core_obs, core_reward, core_term, core_trunc, core_info = core.step(torch.from_numpy(action))
        ret, length = ret + reward, length + 1
        assert reward == float(core_reward[0])
        assert (terminated, truncated) == (bool(core_term[0]), bool(core_trunc[0]))
        assert isinstance(obs, np.ndarray) and obs.dtype == single.observation_space.dtype
        if terminated or truncated:
            np.testing.assert_array_equal(obs, core_info["final_obs"][0].numpy())
            assert info["episode_length"] == length
            assert info["episode_return"] == pytest.approx(ret, rel=1e-5)
            assert info["end_reason"] == core.end_reasons[int(core_info["end_reason"][0])]
            assert (info["end_reason"] == "time_limit") == truncated
            obs, _ = single.reset()
            episodes, ret, length = episodes + 1, 0.0, 0
        else:
            assert info == {}
        np.testing.assert_array_equal(obs, core_obs[0].numpy())
    assert episodes >= 7


@pytest.mark.parametrize("env_id", IDS)
def test_seeded_reset_after_episode_end_is_deterministic(env_id):
    task, preset = IDS[env_id]
    env = TaskGymEnv(task_name=task, preset=preset, task=SHORT_EPISODES)
    first, _ = env.reset(seed=5)
    for _ in range(100):
        _, _, terminated, truncated, _ = env.step(np.ones(1, np.float32))
        if terminated or truncated:
            break
    assert terminated or truncated
    again, _ = env.reset(seed=5)
    np.testing.assert_array_equal(first, again)
    unseeded, _ = env.reset()
    assert not np.array_equal(unseeded, first)


@pytest.mark.parametrize("env_id", IDS)
def test_vector_env_matches_core_env_step_for_step(env_id):
    num_envs, seed = 32, 9
    venv = gym.make_vec(env_id, num_envs=num_envs, vectorization_mode="vector_entry_point", task=SHORT_EPISODES)
    core = core_env(env_id, num_envs, task=SHORT_EPISODES)
    assert isinstance(venv, TaskVectorEnv) and isinstance(venv.env, type(core))
    assert venv.metadata["autoreset_mode"] == AutoresetMode.SAME_STEP
    assert venv.observation_space.shape == (num_envs, *core.obs_shape) and venv.action_space.shape == (num_envs, 1)
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
        assert (final["end_reason"][truncated] == core.end_reasons.index("time_limit")).all()
        assert (final["end_reason"][terminated] >= 2).all(), "a failure or a non-finite state"
    assert saw_truncated
    assert saw_terminated <= bool(core.task_ends), "only a task with failures terminates"
    if core.task_ends and type(core).__name__ == "CartpoleBalanceEnv":
        assert saw_terminated, "random 400 N pushes end balance episodes early (the double pole's 40 N do not)"


@pytest.mark.parametrize("task", cartpole_warp.tasks.names())
def test_wrong_action_count_is_a_clear_error(task):
    venv = TaskVectorEnv(num_envs=4, task_name=task)
    venv.reset(seed=0)
    with pytest.raises(ValueError, match="expected 4 action value"):
        venv.step(np.zeros((3, 1), np.float32))


def test_an_env_count_for_the_single_env_says_where_it_belongs():
    with pytest.raises(ValueError, match=r"gymnasium env is one env; for 8 use gym.make_vec\(id, num_envs=N, "):
        gym.make("cartpole_warp/Cartpole-v0", num_envs=8)


def test_an_unknown_keyword_is_a_type_error_and_the_vector_env_names_its_autoreset_mode():
    """Clients probe with keywords of other envs and retry without them on a TypeError (TorchRL's ``GymEnv`` and
    ``frameskip``), and read ``autoreset_mode`` off the vector env as gymnasium's own vector envs have it."""
    with pytest.raises(TypeError, match="unexpected keyword argument 'frameskip'"):
        gym.make("cartpole_warp/Cartpole-v0", frameskip=1)
    with pytest.raises(TypeError, match="unexpected keyword argument 'frameskip'"):
        gym.make_vec("cartpole_warp/Cartpole-v0", num_envs=2, vectorization_mode="vector_entry_point", frameskip=1)
    vector = gym.make_vec("cartpole_warp/Cartpole-v0", num_envs=2, vectorization_mode="vector_entry_point")
    assert vector.autoreset_mode == gym.vector.AutoresetMode.SAME_STEP == vector.metadata["autoreset_mode"]
    vector.close()


def test_an_async_vector_env_of_a_camera_task_after_a_camera_env_does_not_hang():
    """gymnasium's async vector env forks its workers (Linux's default); a camera env built before in the same process
    used torch's OpenMP threads, which do not survive the fork: the workers' first reset waited forever."""
    import subprocess
    import sys

    code = """
import gymnasium as gym
import cartpole_warp
single = gym.make("cartpole_warp/CartpoleBalanceRGB-v0")
single.reset(seed=0)
vector = gym.make_vec("cartpole_warp/CartpoleBalanceRGB-v0", num_envs=2, vectorization_mode="async")
obs, _ = vector.reset(seed=0)
print(obs.shape)
vector.close()
"""
    result = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300)
    assert result.returncode == 0, result.stderr[-2000:]
    assert result.stdout.strip().endswith(", 64, 64)"), result.stdout


@pytest.mark.parametrize("env_id", [DEFAULT_ID, SWINGUP_ID, DOUBLE_POLE_ID])
def test_the_next_step_autoreset_is_gymnasiums_sync_vector_env_of_the_single_env(env_id):
    """``autoreset_mode="NextStep"``: step for step what gymnasium's own ``SyncVectorEnv`` (NEXT_STEP) makes of the
    single env, over several episode ends; and gymnasium's vector observation wrappers take it."""
    vector = gym.make_vec(env_id, num_envs=1, vectorization_mode="vector_entry_point", autoreset_mode="NextStep",
                          task=SHORT_EPISODES)
    reference = gym.vector.SyncVectorEnv([lambda: gym.make(env_id, task=SHORT_EPISODES)],
                                         autoreset_mode=AutoresetMode.NEXT_STEP)
    assert vector.autoreset_mode == AutoresetMode.NEXT_STEP == vector.metadata["autoreset_mode"]
    np.testing.assert_array_equal(vector.reset(seed=4)[0], reference.reset(seed=4)[0])
    ends = restarts = 0
    for actions in random_actions(60, 1, seed=2):
        got, want = vector.step(actions), reference.step(actions)
        for name, mine, theirs in zip(("obs", "reward", "terminated", "truncated"), got[:4], want[:4]):
            np.testing.assert_array_equal(mine, theirs, err_msg=name)
        if want[2][0] or want[3][0]:
            ends += 1
            assert got[4]["_episode_return"][0] and got[4]["episode_length"][0] == want[4]["episode_length"][0]
            np.testing.assert_allclose(got[4]["episode_return"], want[4]["episode_return"], rtol=1e-6)
        restarts += bool(got[4] == {} and got[1][0] == 0.0 and ends)
    assert ends >= 4 and restarts >= ends - 1
    normalized = gym.wrappers.vector.NormalizeObservation(vector)  # refuses a same-step autoreset
    normalized.reset(seed=0)
    assert np.isfinite(normalized.step(random_actions(1, 1, seed=3)[0])[0]).all()
    vector.close()


def test_an_autoreset_mode_the_env_cannot_keep_is_refused_naming_the_two_it_offers():
    with pytest.raises(ValueError, match=r"must be one of 'SameStep', 'NextStep'.*got 'Disabled'"):
        TaskVectorEnv(num_envs=2, autoreset_mode="Disabled")
