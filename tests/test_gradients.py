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

    stage = rollout.stage_params()
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

    checks = [("q0", i) for i in range(rollout.num_joints)] + [("qd0", i) for i in range(rollout.num_joints)]
    checks += [("actions", 0), ("actions", 2 * (HORIZON // 2)), ("actions", 2 * (HORIZON - 1))]
    checks += [(name, 0) for name in stage]
    results = []
    for name, index in checks:
        step = 1e-2 * max(abs(inputs[name].view(-1)[index].item()), 1.0)
        numeric = (perturbed(name, index, step) - perturbed(name, index, -step)) / (2 * step)
        results.append((name, index, leaves[name].grad.view(-1)[index].item(), numeric))
    scale = max(abs(numeric) for *_, numeric in results)
    wrong = [r for r in results if abs(r[2] - r[3]) > 0.02 * abs(r[3]) + 1e-4 * scale]
    assert not wrong, f"tape vs finite differences (name, index, tape, numeric), scale {scale:.3g}: {wrong}"
    masses = [numeric for name, _, _, numeric in results if name.endswith("_mass_kg")]
    assert len(masses) == rollout.num_joints and all(abs(m) > 1e-4 * scale for m in masses), \
        "every body's mass moves the loss (a solver's inertias derived off the tape would give 0)"


@pytest.mark.parametrize("task", TASKS)
def test_forward_is_the_envs_own_step(task):
    """The rollout's states, observations and rewards equal the env's (reward, observation) after each step from
    the same state under the same actions, at the stage's physics."""
    env = cartpole_warp.tasks.make(task, num_envs=2, device=DEVICE, sim={"gradients": True})
    rollout = DifferentiableRollout(env, horizon=5)
    q0, qd0, actions = start(rollout, seed=3)
    with torch.no_grad():
        out = rollout(q0, qd0, actions=actions)
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
