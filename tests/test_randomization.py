"""Domain randomization: per-env parameters (shapes, units, bounds, the model fields they reach), determinism,
independence across envs, action delay, observation noise, config errors, every registered task. The closed-form
check of each env's physics is in test_physics.py."""

import math

import numpy as np
import pytest
import torch

import cartpole_warp
from cartpole_warp.settings.config import ConfigError

TASKS = cartpole_warp.tasks.names()
RANGES = {"mass_scale": {"cart": [0.5, 2.0], "pole": [0.5, 2.0]}, "inertia_scale": {"pole": [0.8, 1.25]},
          "com_offset_m": {"pole": [-0.1, 0.1]},
          "joint_damping": {"pole": [0.0, 0.05]}, "joint_friction": {"cart": [0.0, 0.5]},
          "actuator_scale": [0.7, 1.3], "gravity_m_s2": [9.0, 10.5], "action_delay_steps": 2}
SHORT = {"episode_length_s": 0.2}
FREE = {"episode_length_s": None, "reset_dist_m": 100.0, "max_pole_angle_rad": 100.0}
"""Balance settings under which no episode ends."""


def rollout(env, actions):
    """Observations and rewards of ``actions`` (steps, N, 1), stacked."""
    out = [torch.cat([env.step(a)[0], env.reward_buf.unsqueeze(1)], dim=1).clone() for a in actions]
    return torch.stack(out)


@pytest.mark.parametrize("task_name", TASKS)
def test_physical_params_shapes_units_bounds_and_model(task_name, make):
    """Every value is (N,) within its configured range around the stage's nominal value, the inertia follows the
    mass and the inertia scale, the task's force per action follows the actuator scale, and the Newton model holds
    what each env reports (mass, inverse mass, inertia, centre of mass, damping, gravity)."""
    env = make(512, task_name=task_name, randomization=RANGES)
    nominal = make(1, task_name=task_name).physical_params()
    params = env.physical_params()
    for name, value in params.items():
        assert value.shape == (512,), name
        assert torch.isfinite(value.float()).all(), name
    for role in ("cart", "pole"):
        scale = params[f"{role}_mass_kg"] / nominal[f"{role}_mass_kg"]
        assert 0.5 <= scale.min() < 0.6 and 1.9 < scale.max() <= 2.0, role
        ratio = params[f"{role}_inertia_kg_m2"] / nominal[f"{role}_inertia_kg_m2"]
        assert torch.allclose(ratio, scale * params[f"{role}_inertia_scale"], rtol=1e-5)
    inertia_scale = params["pole_inertia_scale"]
    assert 0.8 <= inertia_scale.min() < 0.85 and 1.2 < inertia_scale.max() <= 1.25
    assert (params["cart_inertia_scale"] == 1.0).all(), "not randomized: the stage's shape"
    shift = params["pole_com_m"] - nominal["pole_com_m"]
    assert -0.1 <= shift.min() < -0.09 and 0.09 < shift.max() <= 0.1
    assert torch.equal(params["cart_com_m"], nominal["cart_com_m"].expand(512)), "not randomized: the stage's"
    assert params["pole_damping_n_m_s_rad"].min() >= 0 and params["pole_damping_n_m_s_rad"].max() <= 0.05
    assert params["cart_friction_n"].max() <= 0.5 and (params["pole_friction_n_m"] == 0).all()
    assert params["actuator_scale"].min() >= 0.7 and params["actuator_scale"].max() <= 1.3
    assert torch.allclose(params["force_per_action_n"], env.cfg.task.max_push_effort_n * params["actuator_scale"])
    assert params["gravity_m_s2"].min() >= 9.0 and params["gravity_m_s2"].max() <= 10.5
    assert set(params["action_delay_steps"].tolist()) == {0, 1, 2}
    model, roles = env.scene.model, env.scene.role_joints
    bodies = model.joint_child.numpy()[roles]
    mass = model.body_mass.numpy().reshape(512, -1)
    for r, role in enumerate(("cart", "pole")):
        np.testing.assert_allclose(mass[:, bodies[r]], params[f"{role}_mass_kg"].cpu().numpy(), rtol=1e-6)
    np.testing.assert_allclose(model.body_inv_mass.numpy().reshape(512, -1), 1 / mass, rtol=1e-5)
    axis = env.physics.bodies[1].axis
    inertia = model.body_inertia.numpy().reshape(512, -1, 3, 3)[:, bodies[1]]
    np.testing.assert_allclose(inertia @ axis @ axis, params["pole_inertia_kg_m2"].cpu().numpy(), rtol=1e-5)
    hinge = model.joint_X_c.numpy().reshape(512, -1, 7)[:, roles[1], :3]  # the joint in the pole's frame
    com = np.linalg.norm(model.body_com.numpy().reshape(512, -1, 3)[:, bodies[1]] - hinge, axis=1)
    np.testing.assert_allclose(com, params["pole_com_m"].cpu().numpy(), rtol=1e-5)
    damping = model.joint_damping.numpy().reshape(512, -1)[:, env.scene.role_dofs[1]]
    np.testing.assert_allclose(damping, params["pole_damping_n_m_s_rad"].cpu().numpy(), rtol=1e-6)
    gravity = np.linalg.norm(model.gravity.numpy()[:512], axis=1)
    np.testing.assert_allclose(gravity, params["gravity_m_s2"].cpu().numpy(), rtol=1e-6)


def test_parameter_table_names_every_parameter_and_the_docs_say_the_same(make, repo):
    """Every task's ``physical_params()`` are its table's names (per role, then per env) and the task's own after
    them; docs/randomization.md's table gives each quantity's name, unit, preset section, settable and differentiable
    as the code's table does."""
    from cartpole_warp.engine.parameters import QUANTITIES

    for task_name in TASKS:
        env = make(2, task_name=task_name)
        names = [p.name for p in env.physics.table]
        assert list(env.physical_params())[:len(names)] == names, task_name
        assert len(names) == 6 * len(env.joint_roles) + 3
        assert {p.role for p in env.physics.table} == {*env.joint_roles, None}
    text = (repo / "docs" / "randomization.md").read_text()
    rows = {line.split("|")[1].strip().split(" ")[0].strip("`"): [cell.strip() for cell in line.split("|")[1:-1]]
            for line in text.splitlines() if line.startswith("| `")}
    for quantity in QUANTITIES:
        row = rows[quantity.name("<role>", slider=True)]
        assert quantity.slider_unit in row[2] and quantity.hinge_unit in row[2], quantity.key
        assert (row[3].startswith(f"`{quantity.section}`") if quantity.section else row[3].startswith("none")), row
        assert row[4:] == [("yes" if quantity.settable else "no"), ("yes" if quantity.differentiable else "no")], row


def test_default_env_simulates_the_stage(make):
    """Without randomization every env reports the stage's values (the classic cart-pole of 1 kg + 1 kg)."""
    params = {name: value.cpu() for name, value in make(8).physical_params().items()}
    assert (params["cart_mass_kg"] == 1.0).all() and (params["pole_mass_kg"] == 1.0).all()
    assert torch.allclose(params["pole_com_m"], torch.tensor(0.47))
    assert torch.allclose(params["gravity_m_s2"], torch.tensor(9.81))
    assert (params["actuator_scale"] == 1.0).all() and (params["action_delay_steps"] == 0).all()


@pytest.mark.parametrize("solver", ["featherstone", "mujoco"])
def test_same_seed_same_parameters_and_trajectories(solver, make, random_actions):
    """The same seed draws the same parameters, and redraws the same at each episode start (bitwise on the CPU,
    whatever the CPU shards or graph capture); another seed draws others."""
    actions = random_actions(1100, 40)
    runs = []
    for threads, capture in ((1, "on"), (2, "on"), (2, "off")):
        env = make(1100, seed=7, sim={"solver": solver, "cpu_threads": threads, "capture": capture}, task=SHORT,
                   randomization=RANGES)
        first = env.physical_params()
        runs.append((first, rollout(env, actions), env.physical_params()))
    for first, trajectory, last in runs[1:]:
        for name in first:
            assert torch.equal(first[name], runs[0][0][name]), name
            assert torch.equal(last[name], runs[0][2][name]), name
        assert torch.equal(trajectory, runs[0][1])
    assert not torch.equal(runs[0][0]["pole_mass_kg"], runs[0][2]["pole_mass_kg"]), "episode starts redraw"
    other = make(1100, seed=8, sim={"solver": solver}, randomization=RANGES).physical_params()
    assert not torch.equal(other["pole_mass_kg"], runs[0][0]["pole_mass_kg"])


def test_startup_draws_once(make, random_actions):
    """``at='startup'`` keeps each env's draw across its episodes; ``reset()`` draws again (the same for its seed)."""
    env = make(64, task=SHORT, randomization={**RANGES, "at": "startup"})
    first = env.physical_params()
    rollout(env, random_actions(64, 40))
    assert torch.equal(env.physical_params()["pole_mass_kg"], first["pole_mass_kg"])
    env.reset(seed=5)
    again = env.physical_params()["pole_mass_kg"]
    assert not torch.equal(again, first["pole_mass_kg"])
    env.reset(seed=5)
    assert torch.equal(env.physical_params()["pole_mass_kg"], again)


@pytest.mark.parametrize("solver", ["featherstone", "mujoco"])
def test_changing_one_env_changes_no_other(solver, make, random_actions):
    """Heavier pole, weaker actuator and lower gravity in env 3 alone, the pole's friction in env 5 alone (set on an
    env that does not randomize it), its inertia scale in env 6 alone: those envs' trajectories change, every other
    env's stays bitwise the same."""
    actions = random_actions(8, 30, scale=0.3)
    trajectories = []
    for change in (False, True):
        env = make(8, sim={"solver": solver}, task=FREE)
        if change:
            params, index = env.physical_params(), torch.arange(8, device=env.device)
            env.set_physical_params(pole_mass_kg=torch.where(index == 3, 3.0, params["pole_mass_kg"]),
                                    actuator_scale=torch.where(index == 3, 0.5, params["actuator_scale"]),
                                    gravity_m_s2=torch.where(index == 3, 5.0, params["gravity_m_s2"]),
                                    pole_friction_n_m=torch.where(index == 5, 2.0, params["pole_friction_n_m"]),
                                    pole_inertia_scale=torch.where(index == 6, 2.0, params["pole_inertia_scale"]))
        trajectories.append(rollout(env, actions))
    changed = torch.tensor([3, 5, 6])
    others = ~torch.isin(torch.arange(8), changed).to(actions.device)
    assert torch.equal(trajectories[0][:, others], trajectories[1][:, others])
    for e in changed.tolist():
        assert (trajectories[0][:, e] - trajectories[1][:, e]).abs().max() > 0.01, e


def test_action_delay_shifts_the_actions(make, random_actions, device):
    """An env with a delay of d steps moves exactly as an undelayed env given the same actions d steps later (and no
    force before its first)."""
    actions = random_actions(1, 25, scale=0.1).expand(25, 2, 1)
    env = make(2, task=FREE, randomization={"action_delay_steps": 3})
    env.set_physical_params(action_delay_steps=torch.tensor([3, 0], dtype=torch.int32, device=device))
    state = torch.tensor([[0.2, 0.1, 0.05, -0.1]] * 2, device=device)
    env.set_state(state)
    delayed = rollout(env, actions)[:, 0, :4]
    shifted = torch.cat([torch.zeros(3, 2, 1, device=device), actions[:-3]])
    env.set_state(state)
    reference = rollout(env, shifted)[:, 1, :4]
    torch.testing.assert_close(delayed, reference, rtol=0, atol=0)
    with pytest.raises(ValueError, match="at most randomization.action_delay_steps=3"):
        env.set_physical_params(action_delay_steps=torch.tensor([4, 0], dtype=torch.int32, device=device))


def test_observation_noise_is_gaussian_of_its_std(make, device):
    """set_state then observe: the observations differ from the states by zero-mean noise of the configured std;
    rewards and ends see the true state."""
    env = make(4096, randomization={"obs_noise_std": 0.05}, task={"episode_length_s": None})
    states = torch.zeros(4096, 4, device=device)
    noise = env.set_state(states) - states
    assert abs(noise.mean().item()) < 0.002 and noise.std().item() == pytest.approx(0.05, rel=0.02)
    _, reward, *_ = env.step(torch.zeros(4096, 1, device=device))
    assert (reward == 1.0).all(), "upright and still: the reward of the true state"


@pytest.mark.parametrize("randomization, message", [
    ({"mass_scale": {"pole": [2.0, 0.5]}}, "mass_scale.pole: low 2 is above high 0.5"),
    ({"mass_scale": {"pole": [-1.0, 2.0]}}, "mass_scale.pole: low -1 must be > 0"),
    ({"mass_scale": {"pole": [0.5, math.nan]}}, "Input should be a finite number"),
    ({"joint_damping": {"cart": [-0.1, 0.1]}}, "joint_damping.cart: low -0.1 must be >= 0"),
    ({"gravity_m_s2": [12.0, 9.0]}, "gravity_m_s2: low 12 is above high 9"),
    ({"mass_scale": {"wheel": [0.5, 2.0]}}, "unknown joint role 'wheel'; this task's roles: cart, pole"),
    ({"com_offset_m": {"cart": [-0.1, 0.1]}}, "cart body's centre of mass lies on its joint"),
    ({"com_offset_m": {"pole": [-0.6, 0.1]}}, "past the joint"),
    ({"action_delay_steps": -1}, "action_delay_steps"),
    ({"mass": {"pole": [0.5, 2.0]}}, "unknown config key 'randomization.mass'"),
])
def test_bad_ranges_are_one_config_error(randomization, message, make):
    with pytest.raises(ConfigError, match=message):
        make(4, randomization=randomization)


def test_set_physical_params_checks_its_input(make, device):
    env = make(4)
    with pytest.raises(ValueError, match="unknown physical parameter 'pole_inertia_kg_m2'; settable: cart_mass_kg"):
        env.set_physical_params(pole_inertia_kg_m2=torch.ones(4, device=device))
    with pytest.raises(ValueError, match="every mass must be > 0"):
        env.set_physical_params(pole_mass_kg=torch.zeros(4, device=device))
    with pytest.raises(ValueError, match="shape"):
        env.set_physical_params(pole_mass_kg=torch.ones(3, device=device))


def test_robustness_grid_sets_each_cells_parameters(make):
    """The grid's envs hold their cell's factors on the stage's values (cells in the order of the axes' product,
    ``episodes`` envs each); a policy that never pushes keeps no balance pole up in any cell."""
    from cartpole_warp.evaluation.robustness import Axis, evaluate_grid
    from cartpole_warp.evaluation.rollouts import zero_policy

    axes = [Axis("pole_mass_kg", (0.5, 2.0)), Axis("gravity_m_s2", (0.5, 1.0, 1.5))]
    env = make(2 * 3 * 4, task={"episode_length_s": 2.0})
    result = evaluate_grid(env, zero_policy, axes, 4, cartpole_warp.tasks.get("cartpole-balance").solved)
    params = env.physical_params()
    pole = params["pole_mass_kg"].cpu().reshape(2, 3, 4)
    gravity = params["gravity_m_s2"].cpu().reshape(2, 3, 4)
    assert torch.equal(pole, torch.tensor([0.5, 2.0]).reshape(2, 1, 1).expand(2, 3, 4))
    torch.testing.assert_close(gravity, 9.81 * torch.tensor([0.5, 1.0, 1.5]).reshape(1, 3, 1).expand(2, 3, 4))
    assert result.success.shape == (2, 3) and (result.success == 0).all()
    assert result.relative == [True, True]


def test_episode_success_follows_the_tasks_rule():
    """Balance: an episode succeeds when it reaches the time limit. Swing-up: when it also earns >= 0.8 per step."""
    returns, lengths = torch.tensor([450.0, 350.0, 100.0]), torch.tensor([500, 500, 120])
    reached = torch.tensor([True, True, False])
    balance = cartpole_warp.tasks.get("cartpole-balance").solved
    swingup = cartpole_warp.tasks.get("cartpole-swingup").solved
    assert balance.episode_success(returns, lengths, reached).tolist() == [True, True, False]
    assert swingup.episode_success(returns, lengths, reached).tolist() == [True, False, False]


@pytest.mark.parametrize("task_name", TASKS)
def test_robust_preset_randomizes_every_task(task_name, device):
    """``preset="robust"`` (configs/robust.yaml) draws each env's masses, actuator strength and delay, for every
    task, through ``tasks.make`` and ``make_env``."""
    envs = [cartpole_warp.tasks.make(task_name, num_envs=256, device=device, preset="robust")]
    if task_name == cartpole_warp.tasks.DEFAULT_TASK:
        envs.append(cartpole_warp.make_env(num_envs=256, device=device, preset="robust"))
    for env in envs:
        params = env.physical_params()
        assert env.cfg.randomization.on and env.cfg.randomization.action_delay_steps == 2
        assert params["pole_mass_kg"].std() > 0 and params["actuator_scale"].std() > 0
        assert set(params["action_delay_steps"].tolist()) == {0, 1, 2}
        env.close()
