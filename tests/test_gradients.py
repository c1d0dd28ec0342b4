"""Differentiable rollouts (``gradients.rollout``): the tape's gradients against central finite differences of the
same rollout, for the initial states, the actions and every physical parameter, on the balance, the swing-up and the
double pole; the forward pass against the env's own step; the policy's parameters reached through the actions."""

import pytest
import torch
from conftest import DEVICE, sees_images

import cartpole_warp
from cartpole_warp.gradients.rollout import DifferentiableRollout
from cartpole_warp.tools.gradcheck import JacobianCheck, off_stage_physics, random_start

TASKS = ["cartpole-balance", "cartpole-swingup", "cart-double-pole-balance"]
HORIZON = 10


def make_rollout(task: str, num_envs: int = 2, horizon: int = HORIZON) -> DifferentiableRollout:
    env = cartpole_warp.tasks.make(task, num_envs=num_envs, device=DEVICE, sim={"gradients": True})
    return DifferentiableRollout(env, horizon)


def start(rollout: DifferentiableRollout, seed: int = 0):
    """Joint states near rest upright and small actions, (N, joints) and (H, N, 1)."""
    drawn = random_start(rollout, seed)
    return drawn["q0"], drawn["qd0"], drawn["actions"]


@pytest.mark.parametrize("task", TASKS)
def test_gradients_equal_finite_differences(task):
    """Every column of the rollout's Jacobian (each output's gradient by the tape) against central finite differences
    (``tools.gradcheck``: a step ladder, the step chosen without the tape), for the initial states, every action and
    every physical parameter off the stage's and different per env. Measured within 1e-3 on every column of the three
    tasks (docs/benchmarks.md); asserted within 1e-2, for the round-off of other CPUs."""
    rollout = make_rollout(task)
    # friction's tanh(velocity / 0.01) turns within a finite difference's step where a joint stops: the physics is
    # differentiated at the stage's friction, with every other parameter off the stage's
    inputs = random_start(rollout, 0) | off_stage_physics(rollout, friction=False)
    columns = JacobianCheck(rollout, inputs).columns()
    wrong = [(c.name, c.index, f"{c.relative_error:.2e}") for c in columns if c.relative_error > 1e-2]
    assert not wrong, f"tape vs finite differences (input, entry, relative error): {wrong}"
    masses = [c for c in columns if c.name.endswith("_mass_kg")]
    assert len(masses) == 2 * rollout.num_joints and all(float(c.tape.norm()) > 1e-4 for c in masses), \
        "every body's mass moves the outputs (a solver's inertias derived off the tape would give 0)"


STATE_TASKS = [name for name in cartpole_warp.tasks.names() if not sees_images(name)]
"""Every registered task that observes its state (the renderer has no adjoint)."""


@pytest.mark.parametrize("task, sim", [(task, {}) for task in STATE_TASKS] + [
    ("cartpole-balance", {"decimation": 4, "mass_matrix_interval": 2}),
    ("cart-double-pole-balance", {"mass_matrix_interval": 1})])
def test_forward_is_the_envs_own_step(task, sim):
    """The rollout's observations and rewards equal the env's after each step from the same state under the same
    actions, with each env's own physics (every parameter off the stage's, per role), for the mass matrix built at
    every physics step or every other."""
    roles = cartpole_warp.tasks.get(task).env_class.joint_roles
    friction = {"at": "startup", "joint_friction": dict.fromkeys(roles, (0.0, 0.1))}  # the env applies friction
    env = cartpole_warp.tasks.make(task, num_envs=2, device=DEVICE, sim={"gradients": True, **sim},
                                   randomization=friction)
    rollout = DifferentiableRollout(env, horizon=5)
    q0, qd0, actions = start(rollout, seed=3)
    params = off_stage_physics(rollout)
    with torch.no_grad():
        out = rollout(q0, qd0, actions=actions, params=params)
    env.set_physical_params(**params)
    env.set_state(torch.stack([q0, qd0], dim=2).reshape(2, -1))
    for t in range(5):
        obs, reward, terminated, truncated, _ = env.step(actions[t])
        assert not (terminated | truncated).any()
        torch.testing.assert_close(obs, out.obs[t + 1], rtol=0, atol=1e-5)
        torch.testing.assert_close(reward, out.rewards[t], rtol=0, atol=1e-5)


def test_episode_ends_are_the_envs():
    """The rollout reports each episode's end as the env does, at the same step and of the same kind: a pole past the
    task's angle (terminated) and the time limit counted on from each env's ``episode_steps`` (truncated)."""
    env_dt = cartpole_warp.tasks.env_config("cartpole-balance", num_envs=4).sim.env_dt
    env = cartpole_warp.tasks.make("cartpole-balance", num_envs=4, device=DEVICE, sim={"gradients": True},
                                   task={"episode_length_s": 6 * env_dt})
    rollout = DifferentiableRollout(env, horizon=8)
    q0 = torch.tensor([[0.0, 0.0], [0.0, 0.0], [0.0, 0.0], [0.0, 1.56]], device=DEVICE)
    qd0 = torch.tensor([[0.0, 0.0], [0.0, 0.0], [0.0, 0.0], [0.0, 2.0]], device=DEVICE)
    counted = torch.tensor([0, 2, 4, 0], device=DEVICE)
    actions = torch.zeros(8, 4, 1, device=DEVICE)
    with torch.no_grad():
        out = rollout(q0, qd0, actions=actions, episode_steps=counted)
    env.set_state(torch.stack([q0, qd0], dim=2).reshape(4, -1))
    env.episode_length_buf = counted
    first_end = {}
    for t in range(8):
        _, _, terminated, truncated, _ = env.step(actions[t])
        for i in range(4):
            if i not in first_end and (terminated[i] or truncated[i]):
                first_end[i] = (t, "terminated" if terminated[i] else "truncated")
    assert first_end == {0: (5, "truncated"), 1: (3, "truncated"), 2: (1, "truncated"), 3: (0, "terminated")}
    for i, (t, kind) in first_end.items():
        assert not out.ended[:t, i].any() and getattr(out, kind)[t, i], (i, out.end_reason[:, i].tolist())


def test_a_policys_parameters_get_the_gradient_of_the_return():
    rollout = make_rollout("cartpole-balance", horizon=8)
    q0, qd0, _ = start(rollout)
    torch.manual_seed(0)
    policy = torch.nn.Sequential(torch.nn.Linear(4, 8), torch.nn.Tanh(), torch.nn.Linear(8, 1)).to(DEVICE)
    out = rollout(q0, qd0, policy=policy)
    out.rewards.sum().backward()
    weight = policy[2].weight
    assert all(p.grad is not None and p.grad.abs().sum() > 0 for p in policy.parameters())
    step, index = 1e-2, 3
    with torch.no_grad():
        returns = []
        for sign in (1, -1):
            weight.view(-1)[index] += sign * step
            returns.append(rollout(q0, qd0, policy=policy).rewards.sum().item())
            weight.view(-1)[index] -= sign * step
    numeric = (returns[0] - returns[1]) / (2 * step)
    assert weight.grad.view(-1)[index].item() == pytest.approx(numeric, rel=0.02, abs=1e-3)


def test_clear_errors():
    plain = cartpole_warp.tasks.make("cartpole-balance", num_envs=2, device=DEVICE)
    with pytest.raises(ValueError, match="gradients"):
        DifferentiableRollout(plain, horizon=4)
    tiled = cartpole_warp.tasks.make("cartpole-balance", num_envs=2, device=DEVICE,
                                     sim={"gradients": True, "tile_gemm": "on"})
    with pytest.raises(ValueError, match="keeps SolverFeatherstone's dense path .its gradients are checked"):
        DifferentiableRollout(tiled, horizon=4)
    rollout = make_rollout("cartpole-balance", horizon=2)
    q0, qd0, actions = start(rollout)
    with pytest.raises(ValueError, match="not both"):
        rollout(q0, qd0)
    with pytest.raises(ValueError, match="unknown physical parameters"):
        rollout(q0, qd0, actions=actions, params={"pole_length_m": torch.ones(2, device=DEVICE)})


def test_a_result_is_backpropagated_once_and_before_the_next_call():
    rollout = make_rollout("cartpole-balance", horizon=3)
    q0, qd0, actions = start(rollout)
    grads = []
    for _ in range(2):  # the same gradients call after call (each call's tapes start from zero)
        leaf = actions.clone().requires_grad_()
        rollout(q0, qd0, actions=leaf).rewards.sum().backward()
        grads.append(leaf.grad)
    torch.testing.assert_close(grads[0], grads[1], rtol=0, atol=0)
    out = rollout(q0, qd0, actions=actions.clone().requires_grad_())
    out.rewards.sum().backward(retain_graph=True)
    with pytest.raises(RuntimeError, match="once"):
        out.rewards.sum().backward()
    stale = rollout(q0, qd0, actions=actions.clone().requires_grad_())
    rollout(q0, qd0, actions=actions)
    with pytest.raises(RuntimeError, match="stale"):
        stale.rewards.sum().backward()
