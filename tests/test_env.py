"""Batched env machinery (``env.py`` and ``kernels.py``), for every registered task: autoreset, truncation, capture,
sharding, seeding, sizes, bad input, set_state, close; config checks where an env is made."""

import math

import pytest
import torch

import cartpole_warp
from cartpole_warp.engine.kernels import COMMON_ENDS
from cartpole_warp.engine.runtime import shard_bounds
from cartpole_warp.settings.config import MAX_EPISODE_LENGTH

TASKS = cartpole_warp.tasks.names()
SHORT_EPISODES = {"episode_length_s": 0.5}
"""A time limit of 25-30 env steps: every task's rollouts end episodes (the swing-up never terminates)."""


def safe_states(env, n):
    """(n, 2 x joint roles) small, distinct states near the origin (within every task's limits)."""
    width = 2 * len(env.joint_roles)
    offsets = torch.tensor([0.2, 0.1, 0.05, -0.1] * (width // 4 + 1))[:width]
    return (offsets + 0.002 * torch.arange(n).unsqueeze(1)).to(env.device)


def zero_actions(env):
    return torch.zeros(env.num_envs, env.num_actions, device=env.device)


def flat(obs):
    """(N, values) float64: each env's observation in one row; camera frames as 16 fixed random projections of their
    pixels (any changed pixel changes them; whole frames of 1024 envs over a rollout would take gigabytes)."""
    rows = obs.reshape(obs.shape[0], -1).double().cpu()  # the CPU's sums: cuBLAS may sum in another order
    if obs.dim() > 2:
        rows = rows @ torch.randn(rows.shape[1], 16, generator=torch.Generator().manual_seed(0), dtype=torch.float64)
    return rows


def rollout(env, actions_sequence):
    """(steps, N, 3 + 2 x observation size): reward, terminated, truncated, obs, final_obs of each step after a
    reset."""
    env.reset()
    trajectory = []
    for actions in actions_sequence:
        obs, reward, terminated, truncated, info = env.step(actions)
        trajectory.append(torch.cat([reward[:, None].double().cpu(), terminated[:, None].double().cpu(),
                                     truncated[:, None].double().cpu(), flat(obs), flat(info["final_obs"])], dim=1))
    return torch.stack(trajectory)


def episodes_ended(trajectory) -> int:
    return int(trajectory[..., 1:3].sum())


@pytest.mark.parametrize("task", TASKS)
def test_the_raw_env_has_gymnasium_spaces_of_its_sizes_and_a_readable_repr(make, task):
    env = make(num_envs=3, task_name=task)
    obs, _ = env.reset()
    assert env.single_observation_space.shape == env.obs_shape == tuple(obs.shape[1:])
    assert env.observation_space.shape == tuple(obs.shape) and env.observation_space.contains(obs.cpu().numpy())
    assert env.single_action_space.shape == (env.num_actions,) and env.action_space.shape == (3, env.num_actions)
    assert env.action_space.contains(env.action_space.sample())
    text = repr(env)
    assert text.startswith(f"<{type(env).__name__}: 3 envs on {env.device}, observations Box(")
    assert "actions Box(-1.0, 1.0, (1,), float32)" in text and text.endswith(">")


@pytest.mark.parametrize("task", TASKS)
def test_every_task_names_its_end_reasons(task, make):
    env = make(2, task_name=task)
    assert env.end_reasons[:4] == COMMON_ENDS == ("running", "time_limit", "nonfinite_state", "diverged_state")
    assert env.end_reasons[4:] == type(env).task_ends
    assert isinstance(env, cartpole_warp.BatchedEnv) and isinstance(env, cartpole_warp.tasks.get(task).env_class)


@pytest.mark.parametrize("task", TASKS)
def test_masked_reset_touches_only_ended_envs_and_keeps_final_obs(task, make, random_actions, device):
    """Envs 0-9 reach the time limit on this step (their counters set one short of it), the others run on: only the
    ended envs are reset (to the next draw of their RNG), and ``final_obs`` is the observation they ended at."""
    n = 64
    ending = torch.arange(n) < 10
    reference, env, fresh = make(n, task_name=task), make(n, task_name=task), make(n, task_name=task)
    states = safe_states(env, n)
    reference.set_state(states)
    env.set_state(states)
    env.episode_length_buf = torch.where(ending, env.max_episode_length - 1, 0).int().to(device)
    actions = random_actions(n, 1)[0]
    ref_obs, ref_reward, *_ = reference.step(actions)
    obs, reward, terminated, truncated, info = env.step(actions)
    obs, truncated, final, ref_obs = obs.cpu(), truncated.cpu(), info["final_obs"].cpu(), ref_obs.cpu()
    next_reset = fresh.reset()[0].cpu()  # each env's second draw, as the autoreset's (the first went to the start)

    assert torch.equal(truncated, ending) and not terminated.any()
    assert torch.equal(reward, ref_reward), "the ending step is rewarded like any other"
    assert torch.equal(obs[~ending], ref_obs[~ending]), "envs that did not end must be untouched"
    if not env.sees_images:  # the state's final_obs is written for every env; camera frames only where an episode ended
        assert torch.equal(final[~ending], obs[~ending])
    assert torch.equal(final[ending], ref_obs[ending]), "final_obs is the observation before the reset"
    assert torch.equal(obs[ending], next_reset[ending]), "ended envs come back reset"
    assert not torch.equal(obs[ending], ref_obs[ending])
    assert (env.episode_length_buf.cpu()[ending] == 0).all()
    assert (env.episode_length_buf.cpu()[~ending] == 1).all()
    assert (info["end_reason"].cpu()[ending] == env.end_reasons.index("time_limit")).all()
    assert (info["episode_length"].cpu()[ending] == 1).all(), "steps really run since set_state"


@pytest.mark.parametrize("task", TASKS)
def test_the_mirror_signs_are_the_physics_left_right_symmetry(task, make, random_actions):
    """From the mirrored state (every joint position and velocity negated) under mirrored actions, the env gives the
    mirrored observations and the same rewards: what PPO's symmetry augmentation assumes of ``obs_mirror``."""
    n = 16
    env, mirrored = make(n, task_name=task), make(n, task_name=task)
    assert len(env.obs_mirror) == env.num_obs and len(env.action_mirror) == env.num_actions
    obs_signs, action_signs = (torch.tensor(s, device=env.device) for s in (env.obs_mirror, env.action_mirror))
    states = safe_states(env, n) * torch.linspace(-3, 3, n, device=env.device)[:, None]
    env.set_state(states)
    mirrored.set_state(-states)
    obs, obs_m = env.get_state_observations(), mirrored.get_state_observations()  # the signs mirror the state
    torch.testing.assert_close(obs_m, obs * obs_signs)
    running = torch.ones(n, dtype=torch.bool, device=env.device)  # an ended episode restarts from a random state
    for actions in random_actions(n, 10, scale=0.3):
        _, reward, terminated, truncated, _ = env.step(actions)
        _, reward_m, terminated_m, truncated_m, _ = mirrored.step(actions * action_signs)
        obs, obs_m = env.get_state_observations(), mirrored.get_state_observations()
        torch.testing.assert_close(reward_m[running], reward[running], rtol=1e-4, atol=1e-5)
        assert torch.equal(terminated_m[running], terminated[running])
        running &= ~(terminated | truncated)
        torch.testing.assert_close(obs_m[running], obs[running] * obs_signs, rtol=1e-4, atol=1e-4)
    assert running.sum() >= n // 2
    assert (obs * obs_signs - obs)[running].abs().amax() > 0.1, "the states moved away from the mirror plane"


@pytest.mark.parametrize("task", TASKS)
def test_time_outs_are_truncations_not_terminations(task, make, device):
    env = make(16, task_name=task, task={"episode_length_s": 0.1})
    assert env.max_episode_length == math.ceil(0.1 / env.env_dt - 1e-9)
    start = env.set_state(torch.zeros(16, 2 * len(env.joint_roles), device=device))  # at rest, upright: it stays
    start_state = env.get_state_observations()
    total = torch.zeros(16)
    for step in range(1, env.max_episode_length + 1):
        obs, reward, terminated, truncated, info = env.step(zero_actions(env))
        total += reward.cpu()
        assert not terminated.any()
        # all(), not any(), at the limit; before it, no env may truncate
        assert torch.equal(truncated.cpu(), torch.full((16,), step == env.max_episode_length)), f"step {step}"
    assert (info["end_reason"].cpu() == env.end_reasons.index("time_limit")).all()
    assert (info["episode_length"].cpu() == env.max_episode_length).all()
    torch.testing.assert_close(info["episode_return"].cpu(), total)
    assert (total > 0).all()
    torch.testing.assert_close(info["final_obs"], start, rtol=0, atol=1e-6)
    new_state = env.get_state_observations()
    assert (new_state - start_state).abs().amax(dim=1).gt(0).all(), "every env starts over from a random state"


@pytest.mark.parametrize("task", TASKS)
def test_episode_length_buf_assignment_sets_the_counters(task, make, device):
    env = make(8, task_name=task, task={"episode_length_s": 1.0})
    env.set_state(safe_states(env, 8))
    env.episode_length_buf = torch.full((8,), env.max_episode_length - 1, dtype=torch.int32, device=device)
    _, _, terminated, truncated, info = env.step(zero_actions(env))
    assert truncated.all() and not terminated.any()
    assert (info["episode_length"] == 1).all(), "the reported length is the steps really run"
    assert (env.episode_length_buf == 0).all()


@pytest.mark.parametrize("task", TASKS)
def test_episode_statistics_sum_the_rewards(task, make, random_actions):
    n, steps = 32, 150
    env = make(n, seed=5, task_name=task, task={"episode_length_s": 1.0})
    env.reset()
    running = torch.zeros(n)
    lengths = torch.zeros(n, dtype=torch.int32)
    checked = 0
    for actions in random_actions(n, steps, seed=5, scale=0.5):
        _, reward, terminated, truncated, info = env.step(actions)
        running += reward.cpu()
        lengths += 1
        done = (terminated | truncated).cpu()
        if done.any():
            torch.testing.assert_close(info["episode_return"].cpu()[done], running[done], rtol=1e-4, atol=1e-3)
            assert torch.equal(info["episode_length"].cpu()[done], lengths[done])
            checked += int(done.sum())
            running[done], lengths[done] = 0.0, 0
    assert checked >= 2 * n


@pytest.mark.parametrize("solver", ["featherstone", "mujoco"])
@pytest.mark.parametrize("task", TASKS)
def test_captured_step_equals_uncaptured(task, solver, make, random_actions):
    actions = random_actions(64, 35)
    captured = rollout(make(64, task_name=task, sim={"solver": solver, "capture": "on"}, task=SHORT_EPISODES), actions)
    plain = rollout(make(64, task_name=task, sim={"solver": solver, "capture": "off"}, task=SHORT_EPISODES), actions)
    assert episodes_ended(captured) >= 64, "the rollout must include resets"
    torch.testing.assert_close(captured, plain, rtol=0, atol=1e-6)


@pytest.mark.parametrize("task", TASKS)
def test_step_views_are_the_steps_results_and_the_next_step_overwrites_them(task, make, random_actions):
    """``step_views`` gives what ``step`` gives (without the counters' totals), as the env's own buffers."""
    actions = random_actions(16, 30, scale=1.0)
    fresh, viewed = make(16, task_name=task, task=SHORT_EPISODES), make(16, task_name=task, task=SHORT_EPISODES)
    for step_actions in actions:
        expected = fresh.step(step_actions)
        got = viewed.step_views(step_actions)
        for want, have in zip(expected[:4], got[:4], strict=True):
            assert torch.equal(want, have)
        assert set(expected[4]) - set(got[4]) == {"nonfinite_actions", "nonfinite_states", "diverged_states"}
        for key, value in got[4].items():
            assert torch.equal(expected[4][key], value)
    assert got[0].data_ptr() == viewed.obs_buf.data_ptr() and got[1].data_ptr() == viewed.reward_buf.data_ptr()
    kept = got[0].clone()
    viewed.step(actions[0])
    assert not torch.equal(got[0], kept), "the next step wrote into the views"


@pytest.mark.parametrize("task", TASKS)
def test_sharded_threads_give_the_single_scene_trajectory(task, make, random_actions, device):
    """On the CPU 1024 envs split into two scenes stepped in two threads; the split must not change results."""
    sharded = make(1024, task_name=task, sim={"cpu_threads": 2}, task=SHORT_EPISODES)
    assert len(sharded.shards) == (2 if device == "cpu" else 1)
    single = make(1024, task_name=task, sim={"cpu_threads": 1}, task=SHORT_EPISODES)
    assert len(single.shards) == 1
    actions = random_actions(1024, 30)
    reference = rollout(single, actions)
    assert episodes_ended(reference) >= 1024, "the rollout must include resets"
    assert torch.equal(rollout(sharded, actions), reference)
    assert torch.equal(rollout(make(1024, task_name=task, sim={"cpu_threads": 2, "capture": "off"},
                                    task=SHORT_EPISODES), actions), reference)


def test_shard_bounds_cover_the_envs(make):
    assert shard_bounds(4096, "cpu", 2) == [(0, 2048), (2048, 4096)]
    assert shard_bounds(5000, "cpu", 3) == [(0, 1666), (1666, 3333), (3333, 5000)]
    assert shard_bounds(1023, "cpu", 2) == [(0, 1023)], "shards hold at least MIN_ENVS_PER_SHARD envs"
    assert shard_bounds(65536, "cuda:0", 2) == [(0, 65536)]
    assert shard_bounds(4096, "cpu", 2, shardable=False) == [(0, 4096)]
    if make(1024, sim={"cpu_threads": 2}).device == "cpu":
        assert len(make(1024, sim={"solver": "mujoco", "cpu_threads": 2}).shards) == 1, "MuJoCo stays in one scene"


@pytest.mark.parametrize("task", TASKS)
def test_same_seed_same_trajectory_other_seed_differs(task, make, random_actions):
    actions = random_actions(64, 60)
    first = rollout(make(64, seed=11, task_name=task, task=SHORT_EPISODES), actions)
    again = rollout(make(64, seed=11, task_name=task, task=SHORT_EPISODES), actions)
    other = rollout(make(64, seed=12, task_name=task, task=SHORT_EPISODES), actions)
    assert torch.equal(first, again)
    assert not torch.allclose(first, other)


@pytest.mark.parametrize("seed", [-1, "a", 2.0, True, 2**40])
def test_a_seed_that_is_no_int32_is_refused(make, seed):
    env = make(2)
    with pytest.raises(ValueError, match=r"seed: expected a whole number in \[0, 2147479551\] or None, got "):
        env.reset(seed=seed)


@pytest.mark.parametrize("task", TASKS)
def test_reset_with_seed_restarts_the_random_stream(task, make):
    env = make(64, seed=0, task_name=task)
    first = env.reset(seed=7)[0]
    second = env.reset()[0]
    assert not torch.equal(second, first)
    assert torch.equal(env.reset(seed=7)[0], first)


@pytest.mark.parametrize("num_envs", [1, 64, 4096])
@pytest.mark.parametrize("task", TASKS)
def test_sizes(task, num_envs, make, random_actions, device):
    env = make(num_envs, task_name=task)
    assert env.num_obs == cartpole_warp.tasks.get(task).env_class.num_obs and env.num_actions == 1
    camera = env.cfg.camera
    shape, dtype = {"none": ((env.num_obs,), torch.float32),
                    "rgb": ((3 * camera.frame_stack, camera.height_px, camera.width_px), torch.uint8),
                    "depth": ((camera.frame_stack, camera.height_px, camera.width_px), torch.float32)}[camera.image]
    assert env.obs_shape == shape
    obs, info = env.reset()
    assert obs.shape == (num_envs, *shape) and obs.dtype == dtype and str(obs.device) == env.device
    for actions in random_actions(num_envs, 10):
        obs, reward, terminated, truncated, info = env.step(actions)
    assert obs.shape == info["final_obs"].shape == (num_envs, *shape)
    assert env.get_state_observations().shape == (num_envs, env.num_obs)
    assert reward.shape == terminated.shape == truncated.shape == (num_envs,)
    assert reward.dtype == torch.float32 and terminated.dtype == truncated.dtype == torch.bool
    for key in ("episode_return", "episode_length", "end_reason"):
        assert info[key].shape == (num_envs,)
    assert info["end_reason"].dtype == info["episode_length"].dtype == torch.int32
    assert torch.isfinite(obs).all()
    assert env.episode_length_buf.shape == (num_envs,)
    assert env.get_observations().shape == (num_envs, *shape)
    # (N,) actions are accepted as well as (N, 1)
    env.step(torch.zeros(num_envs, device=device))


BAD_ACTIONS = {
    "extra column": (lambda n, a: torch.zeros(n, a + 1), "shape"),
    "too few rows": (lambda n, a: torch.zeros(n // 2, a), "shape"),
    "float64": (lambda n, a: torch.zeros(n, a, dtype=torch.float64), "dtype"),
    "int32": (lambda n, a: torch.zeros(n, a, dtype=torch.int32), "dtype"),
    "other device": (lambda n, a: torch.zeros(n, a, device="meta"), "device"),
    "list": (lambda n, a: [0.0] * (n * a), "list"),
}


@pytest.mark.parametrize("kind", BAD_ACTIONS)
@pytest.mark.parametrize("task", TASKS)
def test_bad_actions_raise_value_error(task, kind, make, device):
    env = make(8, task_name=task)
    build, message = BAD_ACTIONS[kind]
    actions = build(8, env.num_actions)
    if isinstance(actions, torch.Tensor) and actions.device.type != "meta":
        actions = actions.to(device)
    with pytest.raises(ValueError, match=message) as err:
        env.step(actions)
    assert "expected" in str(err.value)


@pytest.mark.parametrize("task", TASKS)
def test_nonfinite_actions_are_applied_as_zero_and_counted(task, make, device):
    env, reference = make(8, task_name=task), make(8, task_name=task)
    states = safe_states(env, 8)
    env.set_state(states)
    reference.set_state(states)
    bad = torch.tensor([[math.nan], [math.inf], [-math.inf], [0.0], [0.0], [0.0], [0.0], [0.0]], device=device)
    obs, reward, *_, info = env.step(bad)
    ref_obs, ref_reward, *_ = reference.step(zero_actions(reference))
    assert torch.equal(obs, ref_obs) and torch.equal(reward, ref_reward)
    assert int(info["nonfinite_actions"]) == 3
    _, _, *_, info = env.step(bad)
    assert int(info["nonfinite_actions"]) == 6, "a running total"


@pytest.mark.parametrize("task", TASKS)
def test_nonfinite_physics_state_is_reset_and_counted(task, make, device):
    env = make(8, task_name=task)
    last_finite = env.set_state(safe_states(env, 8))
    last_finite_state = env.get_state_observations()
    qd = env.scene.state_0.joint_qd
    values = qd.numpy()
    values[3 * env.scene.dofs_per_env + env.scene.role_dofs[-1]] = math.nan
    qd.assign(values)
    obs, reward, terminated, truncated, info = env.step(zero_actions(env))
    assert torch.isfinite(obs).all() and torch.isfinite(info["final_obs"]).all()
    assert int(info["nonfinite_states"]) == 1
    assert terminated.cpu().tolist() == [False, False, False, True, False, False, False, False]
    assert not truncated.any()
    assert env.end_reasons[int(info["end_reason"][3])] == "nonfinite_state"
    assert float(reward[3]) == 0.0 and float(info["episode_return"][3]) == 0.0
    assert int(info["episode_length"][3]) == 1
    assert torch.equal(info["final_obs"][3], last_finite[3]), "the last finite observation"
    assert not torch.equal(env.get_state_observations()[3], last_finite_state[3]), "env 3 starts over"
    assert int(env.episode_length_buf[3]) == 0
    obs, *_, info = env.step(zero_actions(env))
    assert torch.isfinite(obs).all() and int(info["nonfinite_states"]) == 1


@pytest.mark.parametrize("task", TASKS)
def test_runaway_physics_ends_as_diverged_with_finite_rewards_and_bounded_observations(task, make, device):
    """A finite state far beyond anything the task reaches (velocities of 1e4 and 1e6 per joint, positions left
    sound) ends its episode as 'diverged_state' after one step: reward 0, a finite return, the last sound observation
    kept, counted; the other envs run on. Without the guard the double pole's reward at 1e6 rad/s is about -5e8
    (and -inf from about 2e19 on), and the observations carry the runaway values into the policy's normaliser."""
    env = make(4, task_name=task)
    states = safe_states(env, 4)
    velocities = states[:, 1::2]
    velocities[1] = 1e6
    velocities[2] = 1e4
    start = env.set_state(states)
    obs, reward, terminated, truncated, info = env.step(zero_actions(env))
    reasons = [env.end_reasons[code] for code in info["end_reason"].tolist()]
    assert reasons[1:3] == ["diverged_state", "diverged_state"] and reasons[0] == reasons[3] == "running", reasons
    assert terminated.tolist() == [False, True, True, False] and not truncated.any()
    assert reward[1:3].tolist() == [0.0, 0.0] and torch.isfinite(reward).all()
    assert torch.isfinite(info["episode_return"]).all() and info["episode_return"][1:3].tolist() == [0.0, 0.0]
    assert torch.equal(info["final_obs"][1:3], start[1:3]), "the last sound observation: the start's"
    assert int(info["diverged_states"]) == 2 and int(info["nonfinite_states"]) == 0
    limit = env.cfg.sim.divergence_limit
    assert torch.isfinite(obs).all() and (obs[1:3].abs() <= limit).all(), "envs 1 and 2 start over"


@pytest.mark.parametrize("task", TASKS)
def test_set_state_validates_and_masks(task, make, device):
    env, everywhere = make(4, task_name=task), make(4, task_name=task)
    width = 2 * len(env.joint_roles)
    env.reset()
    env.step(zero_actions(env))
    before = env.get_observations()
    states = torch.arange(4 * width, dtype=torch.float32, device=device).reshape(4, width) / 100
    mask = torch.tensor([True, False, True, False], device=device)
    obs = env.set_state(states, mask)
    full = everywhere.set_state(states)
    assert torch.equal(obs[mask], full[mask]) and torch.equal(obs[~mask], before[~mask])
    assert not torch.equal(obs[mask], before[mask])
    assert torch.equal(env.get_observations(), obs)
    assert env.episode_length_buf.cpu().tolist() == [0, 1, 0, 1], "set_state starts new episodes where masked"
    # the next step starts from the set states: as in the env where every state was set
    masked_next, *_ = env.step(zero_actions(env))
    full_next, *_ = everywhere.step(zero_actions(everywhere))
    assert torch.equal(masked_next[mask], full_next[mask])
    with pytest.raises(ValueError, match="finite"):
        env.set_state(torch.full((4, width), math.nan, device=device))
    with pytest.raises(ValueError, match="shape"):
        env.set_state(torch.zeros(4, width - 1, device=device))
    with pytest.raises(ValueError, match="dtype"):
        env.set_state(states, mask.int())
    with pytest.raises(ValueError, match="shape"):
        env.set_state(states, mask[:3])


@pytest.mark.parametrize(
    "kwargs, message",
    [
        ({"num_envs": 0}, "num_envs"),
        ({"sim": {"physics_dt": 0.0}}, "physics_dt"),
        ({"sim": {"physics_dt": -0.01}}, "physics_dt"),
        ({"sim": {"solver": "bullet"}}, "sim.solver: Input should be 'featherstone' or 'mujoco'"),
        ({"sim": {"decimation": 3}}, "mass_matrix_interval"),
        ({"preset": "nonexistent"}, "unknown preset 'nonexistent'"),
        ({"sim": {"no_such_field": 1}}, "unknown config key 'sim.no_such_field'"),
        ({"sim": {"stage_path": "/nonexistent/cartpole.usda"}}, "USD stage not found"),
        ({"device": "tpu"}, "unknown device"),
        ({"num_envs": True}, "num_envs: Input should be a valid integer"),
        ({"num_envs": 2**31}, "would need about 15,032 GB"),
        ({"task": {"reset_dist_m": -1.0}}, "task.reset_dist_m: Input should be greater than 0"),
        ({"task": {"max_pole_angle_rad": 0.0}}, "task.max_pole_angle_rad: Input should be greater than 0"),
        ({"task": {"max_push_effort_n": math.inf}}, "task.max_push_effort_n: Input should be a finite number"),
        ({"task": {"cart_vel_weight": -0.01}}, "task.cart_vel_weight: Input should be greater than or equal to 0"),
        ({"task": {"reset_pole_vel_rad_s": math.nan}}, "task.reset_pole_vel_rad_s: Input should be a finite number"),
        ({"task": {"reset_cart_pos_m": 3.5}}, "must be below task.reset_dist_m"),
        ({"task": {"episode_length_s": math.inf}}, "task.episode_length_s: Input should be a finite number"),
        ({"task": {"episode_length_s": 3.6e7}}, "2,160,000,000 env steps; the step counters hold at most"),
        ({"seed": -1}, "seed: Input should be greater than or equal to 0"),
        ({"task": {"cart_joint": ""}}, "task.cart_joint: String should have at least 1 character"),
        ({"sim": {"cart_joint": "cartJoint"}}, "unknown config key 'sim.cart_joint'"),
    ],
)
def test_invalid_config_names_the_problem(kwargs, message, device):
    kwargs = {"num_envs": 4, "device": device, **kwargs}
    with pytest.raises(cartpole_warp.ConfigError, match=message):
        cartpole_warp.make_env(**kwargs)


def test_unknown_task_and_other_tasks_keys_are_named(device):
    with pytest.raises(cartpole_warp.ConfigError, match="unknown task 'no-such-task'; known tasks: cartpole-balance"):
        cartpole_warp.tasks.make("no-such-task", num_envs=2, device=device)
    with pytest.raises(cartpole_warp.ConfigError, match="unknown config key 'task.reset_dist_m'"):
        cartpole_warp.tasks.make("cartpole-swingup", num_envs=2, device=device, task={"reset_dist_m": 3.0})


@pytest.mark.parametrize("task", TASKS)
def test_the_longest_time_limit_the_counters_hold_still_truncates(task, make, device):
    env_dt = cartpole_warp.tasks.env_config(task).sim.env_dt
    env = make(2, task_name=task, task={"episode_length_s": (MAX_EPISODE_LENGTH - 0.5) * env_dt})
    assert env.max_episode_length == MAX_EPISODE_LENGTH
    env.set_state(torch.zeros(2, 2 * len(env.joint_roles), device=device))
    _, _, _, truncated, _ = env.step(zero_actions(env))
    assert not truncated.any()
    env.episode_length_buf = torch.full((2,), MAX_EPISODE_LENGTH - 1, dtype=torch.int32, device=device)
    _, _, terminated, truncated, info = env.step(zero_actions(env))
    assert truncated.all() and not terminated.any() and (info["episode_length"] == 2).all()


@pytest.mark.parametrize("task", TASKS)
def test_close_stops_the_shard_threads(task, make, device):
    import threading

    def shard_threads():
        return {t for t in threading.enumerate() if t.name.startswith("cartpole-shard")}

    before = shard_threads()
    env = make(1024, task_name=task, sim={"cpu_threads": 2})
    for _ in range(5):
        env.step(zero_actions(env))
    # ThreadPoolExecutor starts a second thread only when the first is busy at the submit: 1 or 2 on the CPU
    assert len(shard_threads() - before) in ((1, 2) if device == "cpu" else (0,))
    env.close()
    assert not (shard_threads() - before)
