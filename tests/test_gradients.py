"""Differentiable rollouts (``gradients.rollout``): the tape's gradients against central finite differences of the
same rollout, for the initial states, the actions and every physical parameter, on the balance, the swing-up and the
double pole; the forward pass against the env's own step; the policy's parameters reached through the actions."""

import pytest
import torch
from conftest import DEVICE

import cartpole_warp
from cartpole_warp.gradients.rollout import DifferentiableRollout

TASKS = ["cartpole-balance", "cartpole-swingup", "cart-double-pole-balance"]
HORIZON = 10


def make_rollout(task: str, num_envs: int = 2, horizon: int = HORIZON) -> DifferentiableRollout:
    env = cartpole_warp.tasks.make(task, num_envs=num_envs, device=DEVICE, sim={"gradients": True})
    return DifferentiableRollout(env, horizon)


def start(rollout: DifferentiableRollout, seed: int = 0):
    """Joint states near rest upright and small actions, (N, joints) and (H, N, 1)."""
    gen = torch.Generator().manual_seed(seed)
    n, j = rollout.num_envs, rollout.num_joints
    q0 = (torch.rand((n, j), generator=gen) - 0.5) * 0.4
    qd0 = (torch.rand((n, j), generator=gen) - 0.5) * 0.4
    actions = (torch.rand((rollout.horizon, n, 1), generator=gen) - 0.5) * 0.6
    return q0.to(DEVICE), qd0.to(DEVICE), actions.to(DEVICE)


@pytest.mark.parametrize("task", TASKS)
def test_gradients_equal_finite_differences(task):
    rollout = make_rollout(task)
    q0, qd0, actions = start(rollout)
    gen = torch.Generator().manual_seed(1)
    weights = [(torch.rand(shape, generator=gen, dtype=torch.float64) - 0.5).to(DEVICE)
               for shape in ((HORIZON, 2), (2, rollout.num_joints), (2, rollout.num_joints))]

    def loss(q0, qd0, actions, params):
        out = rollout(q0, qd0, actions=actions, params=params)
        return ((out.rewards.double() * weights[0]).sum() + (out.q[-1].double() * weights[1]).sum()
                + (out.qd[-1].double() * weights[2]).sum())

    # friction's tanh(velocity / 0.01) turns within a finite difference's step where a joint stops: the physics is
    # differentiated at zero friction (smooth), with every other parameter off the stage's
    stage = physics_per_env(rollout, friction=False)
    inputs = {"q0": q0, "qd0": qd0, "actions": actions, **stage}
    leaves = {name: value.clone().requires_grad_() for name, value in inputs.items()}
    params = {name: leaves[name] for name in stage}
    loss(leaves["q0"], leaves["qd0"], leaves["actions"], params).backward()

    def perturbed(name: str, index: int, step: float) -> float:
        values = {k: v.clone() for k, v in inputs.items()}
        values[name].view(-1)[index] += step
        with torch.no_grad():
            return loss(values["q0"], values["qd0"], values["actions"],
                        {k: values[k] for k in stage}).item()

    entries = 2 * rollout.num_joints  # both envs' joints
    checks = [("q0", i) for i in range(entries)] + [("qd0", i) for i in range(entries)]
    checks += [("actions", 0), ("actions", 2 * (HORIZON // 2) + 1), ("actions", 2 * (HORIZON - 1))]
    checks += [(name, env) for name in stage for env in (0, 1)]
    results = []
    for name, index in checks:
        step = 1e-2 * max(abs(inputs[name].view(-1)[index].item()), 1.0)
        if "_friction_" in name:  # a friction of 0.01 already stiffens a joint at rest (1 per rad/s): smaller steps
            step = 1e-3
        numeric = (perturbed(name, index, step) - perturbed(name, index, -step)) / (2 * step)
        results.append((name, index, leaves[name].grad.view(-1)[index].item(), numeric))
    scale = max(abs(numeric) for *_, numeric in results)
    # a friction's finite difference has steps 10x smaller, and so 10x the float32 noise of the others
    wrong = [r for r in results
             if abs(r[2] - r[3]) > 0.02 * abs(r[3]) + (1e-3 if "_friction_" in r[0] else 1e-4) * scale]
    assert not wrong, f"tape vs finite differences (name, index, tape, numeric), scale {scale:.3g}: {wrong}"
    masses = [numeric for name, _, _, numeric in results if name.endswith("_mass_kg")]
    assert len(masses) == 2 * rollout.num_joints and all(abs(m) > 1e-4 * scale for m in masses), \
        "every body's mass moves the loss (a solver's inertias derived off the tape would give 0)"


def physics_per_env(rollout: DifferentiableRollout, friction: bool = True) -> dict[str, torch.Tensor]:
    """Each parameter different in each env and from the stage's: masses and centres of mass 0.8x and 1.2x, damping
    and (where ``friction``, else none) friction 0.02 and 0.05 (N s/m, N m s/rad; N, N m) times 1 + the role's
    index, actuator scale 0.9 and 1.1, gravity 9.6 and 10.0."""
    out = {}
    for name, value in rollout.stage_params().items():
        role = next((r for r, role in enumerate(rollout.roles) if name.startswith(f"{role}_")), 0)
        if "_friction_" in name and not friction:
            out[name] = value
        elif "_damping_" in name or "_friction_" in name:  # role k's 1 + k times the first's: no two alike
            out[name] = torch.tensor([0.02, 0.05], device=value.device) * (1 + role)
        elif name == "gravity_m_s2":
            out[name] = torch.tensor([9.6, 10.0], device=value.device)
        elif name == "actuator_scale":
            out[name] = torch.tensor([0.9, 1.1], device=value.device)
        else:
            out[name] = value * torch.tensor([0.8, 1.2], device=value.device)
    return out


STATE_TASKS = [name for name in cartpole_warp.tasks.names()
               if "camera" not in cartpole_warp.tasks.get(name).defaults.get("env", {})]
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
    params = physics_per_env(rollout)
    with torch.no_grad():
        out = rollout(q0, qd0, actions=actions, params=params)
    env.set_physical_params(**params)
    env.set_state(torch.stack([q0, qd0], dim=2).reshape(2, -1))
    for t in range(5):
        obs, reward, terminated, truncated, _ = env.step(actions[t])
        assert not (terminated | truncated).any()
        torch.testing.assert_close(obs, out.obs[t + 1], rtol=0, atol=1e-5)
        torch.testing.assert_close(reward, out.rewards[t], rtol=0, atol=1e-5)


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
