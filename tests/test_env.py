"""Batched env behaviour: autoreset, truncation, capture, seeding, sizes, bad input."""

import math

import pytest
import torch
from pxr import Usd, UsdGeom, UsdPhysics

import cartpole_warp
from cartpole_warp.config import MAX_EPISODE_LENGTH, data_path
from cartpole_warp.runtime import shard_bounds
from cartpole_warp.scene import pick_joint

SAFE = torch.tensor([0.2, 0.1, 0.05, -0.1])


def test_masked_reset_touches_only_ended_envs_and_keeps_final_obs(make, random_actions, device):
    n = 64
    ending = torch.arange(n) < 10
    states = SAFE.repeat(n, 1) + 0.01 * torch.arange(n).unsqueeze(1)
    out_of_range = states.clone()
    out_of_range[ending, 0] = 3.5
    reference, env = make(n), make(n)
    reference.set_state(states.to(device))
    env.set_state(out_of_range.to(device))
    actions = random_actions(n, 1)[0]
    ref_obs, *_ = reference.step(actions)
    obs, reward, terminated, truncated, info = env.step(actions)
    obs, terminated, final = obs.cpu(), terminated.cpu(), info["final_obs"].cpu()

    assert torch.equal(terminated, ending) and not truncated.any()
    assert torch.equal(obs[~ending], ref_obs.cpu()[~ending]), "envs that did not end must be untouched"
    assert torch.equal(final[~ending], obs[~ending])
    assert (final[ending, 0] > 3.0).all(), "final_obs is the observation before the reset"
    assert (obs[ending, 0].abs() <= 1.0).all(), "ended envs come back reset"
    assert (reward.cpu()[ending] == -2.0).all()
    assert (env.episode_length_buf.cpu()[ending] == 0).all()
    assert (env.episode_length_buf.cpu()[~ending] == 1).all()
    assert (info["end_reason"].cpu()[ending] == 1).all()


def test_time_outs_are_truncations_not_terminations(make, device):
    env = make(16, task={"episode_length_s": 0.1})
    assert env.max_episode_length == math.ceil(0.1 / env.env_dt)
    env.set_state(torch.zeros(16, 4, device=device))
    zero = torch.zeros(16, 1, device=device)
    for step in range(1, env.max_episode_length + 1):
        obs, reward, terminated, truncated, info = env.step(zero)
        assert not terminated.any()
        assert truncated.all() == (step == env.max_episode_length)
    assert (info["end_reason"].cpu() == 3).all()
    assert (info["episode_length"].cpu() == env.max_episode_length).all()
    torch.testing.assert_close(info["episode_return"].cpu(), torch.full((16,), float(env.max_episode_length)))
    assert (info["final_obs"].cpu() == 0).all() and (obs.cpu()[:, 0].abs() > 0).any()


def test_episode_length_buf_assignment_sets_the_counters(make, device):
    env = make(8, task={"episode_length_s": 1.0})
    env.set_state(torch.zeros(8, 4, device=device))
    env.episode_length_buf = torch.full((8,), env.max_episode_length - 1, dtype=torch.int32, device=device)
    _, _, terminated, truncated, info = env.step(torch.zeros(8, 1, device=device))
    assert truncated.all() and not terminated.any()
    assert (info["episode_length"] == 1).all(), "the reported length is the steps really run"


def test_episode_statistics_sum_the_rewards(make, random_actions):
    n, steps = 32, 150
    env = make(n, seed=5)
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
    assert checked >= n


def rollout(env, actions_sequence):
    env.reset()
    trajectory = []
    for actions in actions_sequence:
        obs, reward, terminated, truncated, info = env.step(actions)
        trajectory.append(torch.cat([obs, reward[:, None], terminated[:, None], truncated[:, None],
                                     info["final_obs"]], dim=1).cpu())
    return torch.stack(trajectory)


@pytest.mark.parametrize("solver", ["featherstone", "mujoco"])
def test_captured_step_equals_uncaptured(solver, make, random_actions):
    actions = random_actions(64, 120)
    captured = rollout(make(64, sim={"solver": solver, "capture": "on"}), actions)
    plain = rollout(make(64, sim={"solver": solver, "capture": "off"}), actions)
    assert captured[..., 5].sum() > 0, "the rollout must include terminations"
    torch.testing.assert_close(captured, plain, rtol=0, atol=1e-6)


def test_sharded_threads_give_the_single_scene_trajectory(make, random_actions, device):
    """On the CPU 1024 envs split into two scenes stepped in two threads; the split must not change results."""
    sharded = make(1024, sim={"cpu_threads": 2})
    assert len(sharded.shards) == (2 if device == "cpu" else 1)
    single = make(1024, sim={"cpu_threads": 1})
    assert len(single.shards) == 1
    actions = random_actions(1024, 80)
    reference = rollout(single, actions)
    assert reference[..., 5].sum() > 0, "the rollout must include terminations"
    assert torch.equal(rollout(sharded, actions), reference)
    assert torch.equal(rollout(make(1024, sim={"cpu_threads": 2, "capture": "off"}), actions), reference)


def test_shard_bounds_cover_the_envs(make):
    assert shard_bounds(4096, "cpu", 2) == [(0, 2048), (2048, 4096)]
    assert shard_bounds(5000, "cpu", 3) == [(0, 1666), (1666, 3333), (3333, 5000)]
    assert shard_bounds(1023, "cpu", 2) == [(0, 1023)], "shards hold at least MIN_ENVS_PER_SHARD envs"
    assert shard_bounds(65536, "cuda:0", 2) == [(0, 65536)]
    assert shard_bounds(4096, "cpu", 2, shardable=False) == [(0, 4096)]
    if make(1024, sim={"cpu_threads": 2}).device == "cpu":
        assert len(make(1024, sim={"solver": "mujoco", "cpu_threads": 2}).shards) == 1, "MuJoCo stays in one scene"


def test_same_seed_same_trajectory_other_seed_differs(make, random_actions):
    actions = random_actions(64, 100)
    first = rollout(make(64, seed=11), actions)
    again = rollout(make(64, seed=11), actions)
    other = rollout(make(64, seed=12), actions)
    assert torch.equal(first, again)
    assert not torch.allclose(first, other)


def test_reset_with_seed_restarts_the_random_stream(make):
    env = make(64, seed=0)
    first = env.reset(seed=7)[0]
    env.reset()
    assert torch.equal(env.reset(seed=7)[0], first)


@pytest.mark.parametrize("num_envs", [1, 64, 4096])
def test_sizes(num_envs, make, random_actions, device):
    env = make(num_envs)
    obs, info = env.reset()
    assert obs.shape == (num_envs, 4) and obs.dtype == torch.float32 and str(obs.device) == env.device
    for actions in random_actions(num_envs, 30):
        obs, reward, terminated, truncated, info = env.step(actions)
    assert reward.shape == terminated.shape == truncated.shape == (num_envs,)
    assert terminated.dtype == torch.bool and info["final_obs"].shape == (num_envs, 4)
    assert torch.isfinite(obs).all()
    assert env.episode_length_buf.shape == (num_envs,)
    # (N,) actions are accepted as well as (N, 1)
    env.step(torch.zeros(num_envs, device=device))


@pytest.mark.parametrize(
    "actions, message",
    [
        (torch.zeros(8, 2), "shape"),
        (torch.zeros(4, 1), "shape"),
        (torch.zeros(8, 1, dtype=torch.float64), "dtype"),
        (torch.zeros(8, 1, dtype=torch.int32), "dtype"),
        (torch.zeros(8, 1, device="meta"), "device"),
        ([0.0] * 8, "list"),
    ],
)
def test_bad_actions_raise_value_error(actions, message, make, device):
    env = make(8)
    if isinstance(actions, torch.Tensor) and actions.device.type != "meta":
        actions = actions.to(device)
    with pytest.raises(ValueError, match=message) as err:
        env.step(actions)
    assert "expected" in str(err.value)


def test_nonfinite_actions_are_applied_as_zero_and_counted(make, device):
    env, reference = make(8), make(8)
    states = SAFE.repeat(8, 1).to(device)
    env.set_state(states)
    reference.set_state(states)
    bad = torch.tensor([[math.nan], [math.inf], [-math.inf], [0.0], [0.0], [0.0], [0.0], [0.0]], device=device)
    obs, *_, info = env.step(bad)
    ref_obs, *_ = reference.step(torch.zeros(8, 1, device=device))
    assert torch.equal(obs, ref_obs)
    assert int(info["nonfinite_actions"]) == 3


def test_nonfinite_physics_state_is_reset_and_counted(make, device):
    env = make(8)
    env.set_state(SAFE.repeat(8, 1).to(device))
    last_finite = env.get_observations()
    qd = env.scene.state_0.joint_qd
    values = qd.numpy()
    values[3 * env.scene.dofs_per_env + env.scene.pole_dof] = math.nan
    qd.assign(values)
    obs, reward, terminated, truncated, info = env.step(torch.zeros(8, 1, device=device))
    assert torch.isfinite(obs).all() and torch.isfinite(info["final_obs"]).all()
    assert int(info["nonfinite_states"]) == 1
    assert terminated.cpu().tolist() == [False, False, False, True, False, False, False, False]
    assert int(info["end_reason"][3]) == 4 and float(reward[3]) == -2.0
    assert torch.equal(info["final_obs"][3], last_finite[3])
    obs, *_ = env.step(torch.zeros(8, 1, device=device))
    assert torch.isfinite(obs).all()


def test_set_state_validates_and_masks(make, device):
    env = make(4)
    env.reset()
    before = env.get_observations()
    states = torch.arange(16, dtype=torch.float32, device=device).reshape(4, 4) / 100
    mask = torch.tensor([True, False, True, False], device=device)
    obs = env.set_state(states, mask)
    assert torch.equal(obs[mask], states[mask]) and torch.equal(obs[~mask], before[~mask])
    with pytest.raises(ValueError, match="finite"):
        env.set_state(torch.full((4, 4), math.nan, device=device))
    with pytest.raises(ValueError, match="shape"):
        env.set_state(torch.zeros(4, 3, device=device))


def write_stage_with_renamed_joint(path):
    stage = Usd.Stage.Open(str(data_path("usd", "cartpole.usda")))
    stage.GetRootLayer().Export(str(path))
    stage = Usd.Stage.Open(str(path))
    UsdPhysics.RevoluteJoint(stage.GetPrimAtPath("/cartpole/poleJoint")).GetPrim().SetActive(False)
    stage.GetRootLayer().Save()


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
        ({"sim": {"cart_joint": ""}}, "sim.cart_joint: String should have at least 1 character"),
    ],
)
def test_invalid_config_names_the_problem(kwargs, message, device):
    kwargs = {"num_envs": 4, "device": device, **kwargs}
    with pytest.raises(cartpole_warp.ConfigError, match=message):
        cartpole_warp.make_env(**kwargs)


def test_malformed_stage_and_missing_joint(tmp_path, device):
    garbage = tmp_path / "garbage.usda"
    garbage.write_text("#usda 1.0\nthis is not usd {")
    with pytest.raises(cartpole_warp.StageError, match="cannot load USD stage"):
        cartpole_warp.make_env(num_envs=2, device=device, sim={"stage_path": str(garbage)})
    renamed = tmp_path / "no_pole_joint.usda"
    write_stage_with_renamed_joint(renamed)
    with pytest.raises(cartpole_warp.StageError, match="no joint named 'poleJoint' for the pole joint"):
        cartpole_warp.make_env(num_envs=2, device=device, sim={"stage_path": str(renamed)})


def edited_stage(path, edit):
    """Our stage, exported to ``path`` and changed by ``edit(stage)``."""
    stage = Usd.Stage.Open(str(data_path("usd", "cartpole.usda")))
    stage.GetRootLayer().Export(str(path))
    stage = Usd.Stage.Open(str(path))
    edit(stage)
    stage.GetRootLayer().Save()
    return str(path)


def revolute_cart_joint(stage):
    stage.RemovePrim("/cartpole/cartJoint")
    joint = UsdPhysics.RevoluteJoint.Define(stage, "/cartpole/cartJoint")
    joint.CreateBody0Rel().SetTargets(["/cartpole/rail"])
    joint.CreateBody1Rel().SetTargets(["/cartpole/cart"])
    joint.CreateAxisAttr("X")


def spherical_pole_joint(stage):
    stage.RemovePrim("/cartpole/poleJoint")
    joint = UsdPhysics.SphericalJoint.Define(stage, "/cartpole/poleJoint")
    joint.CreateBody0Rel().SetTargets(["/cartpole/cart"])
    joint.CreateBody1Rel().SetTargets(["/cartpole/pole"])
    joint.CreateLocalPos0Attr((0.12, 0.0, 0.0))


def swinging_rail(stage):
    stage.RemovePrim("/cartpole/railJoint")
    joint = UsdPhysics.RevoluteJoint.Define(stage, "/cartpole/railJoint")
    joint.CreateBody1Rel().SetTargets(["/cartpole/rail"])
    joint.CreateAxisAttr("Z")


@pytest.mark.parametrize("edit, message", [
    (lambda stage: UsdGeom.SetStageMetersPerUnit(stage, 0.01), "metersPerUnit=0.01"),
    (lambda stage: UsdPhysics.SetStageKilogramsPerUnit(stage, 0.001), "kilogramsPerUnit=0.001"),
    (revolute_cart_joint, "the cart joint /cartpole/cartJoint of .* is revolute; it must be prismatic"),
    (spherical_pole_joint, "the pole joint /cartpole/poleJoint of .* is ball; it must be revolute"),
    (swinging_rail, "only the cart and pole joints may move, but it also has /cartpole/railJoint \\(revolute\\)"),
])
def test_stages_the_task_cannot_use_are_named(tmp_path, device, edit, message):
    stage = edited_stage(tmp_path / "edited.usda", edit)
    with pytest.raises(cartpole_warp.StageError, match=message):
        cartpole_warp.make_env(num_envs=2, device=device, sim={"stage_path": stage})


def test_joint_names_resolve_to_one_joint_or_name_the_candidates():
    labels = ["/a/slide", "/b/slide", "/a/hinge"]
    assert pick_joint(labels, "hinge", "pole joint") == 2
    assert pick_joint(labels, "/b/slide", "cart joint") == 1
    with pytest.raises(cartpole_warp.StageError, match="2 joints match 'slide' for the cart joint: /a/slide, /b/slide"):
        pick_joint(labels, "slide", "cart joint")
    with pytest.raises(cartpole_warp.StageError, match="no joint named 'wheel' .* sim.pole_joint"):
        pick_joint(labels, "wheel", "pole joint")


def test_the_longest_time_limit_the_counters_hold_still_truncates(make, device):
    env = make(2, task={"episode_length_s": MAX_EPISODE_LENGTH / 60})
    assert env.max_episode_length == MAX_EPISODE_LENGTH
    env.set_state(torch.zeros(2, 4, device=device))
    _, _, _, truncated, _ = env.step(torch.zeros(2, 1, device=device))
    assert not truncated.any()
    env.episode_length_buf = torch.full((2,), MAX_EPISODE_LENGTH - 1, dtype=torch.int32, device=device)
    _, _, terminated, truncated, info = env.step(torch.zeros(2, 1, device=device))
    assert truncated.all() and not terminated.any() and (info["episode_length"] == 2).all()


def test_a_finite_state_beyond_the_limits_ends_for_that_reason(make, device):
    env = make(3)
    env.set_state(torch.tensor([[1e6, 0.0, 0.0, 0.0], [-1e6, 0.0, 0.3, 0.0], [0.0, 0.0, 3.0, 0.0]], device=device))
    _, reward, terminated, _, info = env.step(torch.zeros(3, 1, device=device))
    assert info["end_reason"].tolist() == [1, 1, 2], "cart out of range, cart out of range, pole fell"
    assert terminated.all() and (reward == -2.0).all() and torch.isfinite(info["final_obs"]).all()


def test_close_stops_the_shard_threads(make, device):
    import threading

    def shard_threads():
        return {t for t in threading.enumerate() if t.name.startswith("cartpole-shard")}

    before = shard_threads()
    env = make(1024, sim={"cpu_threads": 2})
    env.step(torch.zeros(1024, 1, device=device))
    assert len(shard_threads() - before) == (2 if device == "cpu" else 0)
    env.close()
    assert not (shard_threads() - before)
