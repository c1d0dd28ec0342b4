"""The simulator's gradients against finite differences: every column of a differentiable rollout's Jacobian, for
each physical parameter, initial joint state and action of a state task.

    python -m cartpole_warp.tools.gradcheck --task cartpole-swingup
    python -m cartpole_warp.tools.gradcheck --task cart-double-pole-balance --horizon 20 --device cuda:0

The rollout (``gradients.DifferentiableRollout``): 2 envs, ``--horizon`` env steps from random joint states near
upright under random actions, each physical parameter off the stage's value and different per env
(``off_stage_physics``). Its outputs: every step's rewards and the last joint positions and velocities. The tape's
column of an input is the gradient of each output (one backward pass per output); the finite difference's is a
central difference of the output vector, its step chosen from a ladder that halves from 100% of the input's value (or
of 1, if larger): the step where the differences of three neighbouring steps agree best (a plateau between the
truncation error of large steps and the float32 round-off of small ones), each difference Richardson-extrapolated
from two neighbouring steps. The step is chosen without the tape's answer. Written here because numdifftools' step
selection assumes an exact function: on this float32 simulation its steps shrink into the round-off
(docs/benchmarks.md). Each row: the relative error of the tape's column
against the finite difference's (the norm of their difference over the difference's norm).
"""

from __future__ import annotations

import math
import sys
from dataclasses import dataclass

import torch

from .. import tasks
from ..cli import clean_errors, parse, quiet_libraries
from ..engine.parameters import ACTUATOR_SCALE, DAMPING, FRICTION, GRAVITY
from ..engine.scene import StageError
from ..gradients.rollout import DifferentiableRollout
from ..settings.config import ConfigError, require

LADDER_TOP = 1.0
"""The largest finite-difference step, as a fraction of the input's size (or of 1, if larger)."""
LADDER_STEPS = 15
"""Steps on the ladder, each half the one before."""


def off_stage_physics(rollout: DifferentiableRollout, friction: bool = True) -> dict[str, torch.Tensor]:
    """Each parameter different in each of 2 envs and from the stage's: masses and centres of mass 0.8x and 1.2x,
    damping and (where ``friction``, else the stage's) friction 0.02 and 0.05 (N s/m, N m s/rad; N, N m) times 1 +
    the role's index, actuator scale 0.9 and 1.1, gravity 9.6 and 10.0."""
    out = {}
    table = {p.name: p for p in rollout.parameter_table}
    for name, value in rollout.stage_params().items():
        quantity, role = table[name].quantity, table[name].role_index
        if quantity is FRICTION and not friction:
            out[name] = value
        elif quantity in (DAMPING, FRICTION):  # role k's 1 + k times the first's: no two alike
            out[name] = torch.tensor([0.02, 0.05], device=value.device) * (1 + role)
        elif quantity is GRAVITY:
            out[name] = torch.tensor([9.6, 10.0], device=value.device)
        elif quantity is ACTUATOR_SCALE:
            out[name] = torch.tensor([0.9, 1.1], device=value.device)
        else:
            out[name] = value * torch.tensor([0.8, 1.2], device=value.device)
    return out


def random_start(rollout: DifferentiableRollout, seed: int) -> dict[str, torch.Tensor]:
    """Joint positions and velocities within +-0.2 of rest upright (N, joints) and actions within +-0.3 (H, N, 1)."""
    gen = torch.Generator().manual_seed(seed)
    n, j = rollout.num_envs, rollout.num_joints
    q0 = (torch.rand((n, j), generator=gen) - 0.5) * 0.4
    qd0 = (torch.rand((n, j), generator=gen) - 0.5) * 0.4
    actions = (torch.rand((rollout.horizon, n, 1), generator=gen) - 0.5) * 0.6
    return {"q0": q0.to(rollout.device), "qd0": qd0.to(rollout.device), "actions": actions.to(rollout.device)}


@dataclass
class Column:
    """One input's Jacobian column, by the tape and by finite differences."""

    name: str
    index: int
    value: float
    tape: torch.Tensor
    numeric: torch.Tensor
    step: float
    plateau: float
    """How far the finite differences of the chosen step and its neighbours spread (relative to the column's norm)."""

    @property
    def relative_error(self) -> float:
        norm = float(self.numeric.norm())
        difference = float((self.tape - self.numeric).norm())
        return difference / norm if norm > 0 else (0.0 if difference == 0 else math.inf)


class JacobianCheck:
    """A rollout's outputs as a function of its inputs (``inputs``: initial states, actions, physical parameters)."""

    def __init__(self, rollout: DifferentiableRollout, inputs: dict[str, torch.Tensor]):
        self.rollout, self.inputs = rollout, inputs
        self.physics = [name for name in inputs if name in rollout.parameter_names]
        self.positive = {p.name for p in rollout.parameter_table if p.quantity.positive}

    def outputs(self, inputs: dict[str, torch.Tensor]) -> torch.Tensor:
        """Every step's rewards, then the last joint positions and velocities, flat, in float64."""
        out = self.rollout(inputs["q0"], inputs["qd0"], actions=inputs["actions"],
                           params={name: inputs[name] for name in self.physics})
        return torch.cat([out.rewards.flatten(), out.q[-1].flatten(), out.qd[-1].flatten()]).double()

    def tape_jacobian(self) -> dict[str, torch.Tensor]:
        """Per input, (outputs, its entries): one forward and backward pass per output (a rollout's result is
        backpropagated once)."""
        rows = []
        with torch.no_grad():
            count = self.outputs(self.inputs).numel()
        for m in range(count):
            leaves = {name: value.clone().requires_grad_() for name, value in self.inputs.items()}
            self.outputs(leaves)[m].backward()
            rows.append({name: leaf.grad.flatten().double() for name, leaf in leaves.items()})
        return {name: torch.stack([row[name] for row in rows]) for name in self.inputs}

    def central(self, name: str, index: int, step: float) -> torch.Tensor:
        values = []
        for sign in (1.0, -1.0):
            inputs = {k: v.clone() for k, v in self.inputs.items()}
            inputs[name].view(-1)[index] += sign * step
            with torch.no_grad():
                values.append(self.outputs(inputs))
        return (values[0] - values[1]) / (2 * step)

    def column(self, name: str, index: int, tape: torch.Tensor) -> Column:
        value = float(self.inputs[name].view(-1)[index])
        top = LADDER_TOP * max(abs(value), 1.0)
        if name in self.positive:
            top = min(top, 0.5 * abs(value))
        steps = [top * 0.5 ** k for k in range(LADDER_STEPS)]
        centrals = [self.central(name, index, step) for step in steps]
        columns = [(4 * b - a) / 3 for a, b in zip(centrals, centrals[1:])]  # Richardson: h^2 errors cancel
        gaps = [float((a - b).norm()) for a, b in zip(columns, columns[1:])]
        gaps = [gap if math.isfinite(gap) else math.inf for gap in gaps]
        spread = [max(a, b) for a, b in zip(gaps, gaps[1:])]
        best = min(range(len(spread)), key=spread.__getitem__)
        numeric = columns[best + 1]
        norm = float(numeric.norm())
        return Column(name, index, value, tape.cpu(), numeric.cpu(), steps[best + 2],
                      spread[best] / norm if norm > 0 else spread[best])

    def columns(self) -> list[Column]:
        tape = self.tape_jacobian()
        return [self.column(name, index, tape[name][:, index]) for name, value in self.inputs.items()
                for index in range(value.numel())]


@dataclass
class GradcheckArgs:
    task: str = tasks.DEFAULT_TASK
    """A registered task that observes its state."""
    device: str = "cpu"
    """'cpu' or 'cuda:N'."""
    horizon: int = 10
    """Env steps of the rollout."""
    seed: int = 0
    """Seed of the start states and actions."""
    tolerance: float = 1e-3
    """The relative error the summary counts against."""


def main(argv: list[str] | None = None) -> int:
    quiet_libraries()
    with clean_errors(ConfigError, StageError, ValueError):  # ValueError: a task the rollout cannot run
        args = parse(GradcheckArgs, GradcheckArgs(), sys.argv[1:] if argv is None else argv, __doc__)
        require(args.horizon >= 1, f"--horizon must be >= 1, got {args.horizon}")
        require(args.tolerance > 0, f"--tolerance must be > 0, got {args.tolerance}")
        env = tasks.make(args.task, num_envs=2, device=args.device, sim={"gradients": True})
        rollout = DifferentiableRollout(env, args.horizon)
    # friction's tanh(velocity / 0.01) turns within a step where a joint stops: checked at the stage's friction
    inputs = random_start(rollout, args.seed) | off_stage_physics(rollout, friction=False)
    columns = JacobianCheck(rollout, inputs).columns()
    print(f"{args.task}, {args.device}: 2 envs, {args.horizon} env steps; a Jacobian column per input "
          f"({columns[0].tape.numel()} outputs)")
    print(f"{'input':<26} {'entry':>5} {'value':>10} {'|column|':>10} {'relative error':>15} {'step':>9} "
          f"{'plateau':>9}")
    for c in columns:
        print(f"{c.name:<26} {c.index:>5} {c.value:>10.4g} {float(c.numeric.norm()):>10.4g} "
              f"{c.relative_error:>15.2e} {c.step:>9.2g} {c.plateau:>9.1e}")
    errors = [c.relative_error for c in columns]
    worst = max(columns, key=lambda c: c.relative_error)
    physics = [c for c in columns if c.name in rollout.parameter_names]
    within = sum(c.relative_error <= args.tolerance for c in physics)
    print(f"physical parameters: {within} of {len(physics)} columns within {args.tolerance:g}; all inputs: "
          f"{sum(e <= args.tolerance for e in errors)} of {len(errors)}; the worst {worst.relative_error:.2e} "
          f"({worst.name}[{worst.index}])")
    return 0


if __name__ == "__main__":
    sys.exit(main())
