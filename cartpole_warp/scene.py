"""USD stage -> Newton model replicated ``num_envs`` times -> solver.

Build order (as in Newton's examples): ModelBuilder -> add_usd -> replicate -> finalize -> solver ->
state_0 / state_1 / control. The cart and pole DOFs are found by joint name; everything physical
(masses, lengths, limits, gravity) comes from the stage.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import newton

from .config import ConfigError, SimConfig
from .runtime import init_warp

CART_JOINT = "cartJoint"
POLE_JOINT = "poleJoint"
SHARDABLE_SOLVERS = ("featherstone",)
"""Solvers whose CPU scenes can step in parallel threads; mujoco-warp's tile kernels share one CPU arena, so
concurrent replays of MuJoCo scenes abort."""


class StageError(ConfigError):
    """The USD stage is missing, unreadable or lacks the cartpole joints."""


@dataclass
class Scene:
    """A finalized Newton model of ``num_envs`` cartpoles (one world each) and the solver that steps it."""

    model: newton.Model
    solver: newton.solvers.SolverBase
    state_0: newton.State
    state_1: newton.State
    control: newton.Control
    num_envs: int
    dofs_per_env: int
    """Joint coordinates (= DOFs, all joints being 1-DOF) of one cartpole."""
    cart_dof: int
    """Index of the cart DOF inside one env's block of joint_q / joint_qd / joint_f."""
    pole_dof: int
    """Index of the pole DOF inside one env's block."""

    def simulate(self, physics_dt: float, steps: int):
        """Advance every env ``steps`` physics steps; the result ends in ``state_0`` (graph-capturable)."""
        for _ in range(steps):
            self.solver.step(self.state_0, self.state_1, self.control, None, physics_dt)
            self.state_0, self.state_1 = self.state_1, self.state_0
        if steps % 2 == 1:
            self.state_1.assign(self.state_0)
            self.state_0, self.state_1 = self.state_1, self.state_0


def load_cartpole(stage_path: Path) -> tuple[newton.ModelBuilder, int, int]:
    """One cartpole from the stage: (builder, cart_dof, pole_dof)."""
    path = Path(stage_path)
    if not path.is_file():
        raise StageError(f"USD stage not found: {path}")
    builder = newton.ModelBuilder()
    newton.solvers.SolverMuJoCo.register_custom_attributes(builder)
    try:
        builder.add_usd(str(path), enable_self_collisions=False, collapse_fixed_joints=True)
    except Exception as err:  # usd-core and the importer raise many types; name the file once
        raise StageError(f"cannot load USD stage {path}: {type(err).__name__}: {err}") from err
    names = [label.rsplit("/", 1)[-1] for label in builder.joint_label]
    missing = [name for name in (CART_JOINT, POLE_JOINT) if name not in names]
    if missing:
        raise StageError(f"stage {path} has no joint named {' or '.join(missing)}; its joints: {names or 'none'}")
    if builder.joint_dof_count != len(names) or builder.joint_coord_count != len(names):
        raise StageError(f"stage {path}: every joint must have one DOF (prismatic or revolute); joints: {names}")
    cart_dof = builder.joint_qd_start[names.index(CART_JOINT)]
    pole_dof = builder.joint_qd_start[names.index(POLE_JOINT)]
    return builder, cart_dof, pole_dof


def make_solver(model: newton.Model, sim: SimConfig) -> newton.solvers.SolverBase:
    """The configured solver, set up for a frictionless, undamped cartpole without contacts."""
    if sim.solver == "featherstone":
        return newton.solvers.SolverFeatherstone(
            model, angular_damping=0.0, update_mass_matrix_interval=sim.mass_matrix_interval
        )
    return newton.solvers.SolverMuJoCo(model, disable_contacts=True)


def build_scene(num_envs: int, device: str, sim: SimConfig) -> Scene:
    """Load the stage, replicate it ``num_envs`` times into separate worlds, finalize and make the solver."""
    init_warp()
    cartpole, cart_dof, pole_dof = load_cartpole(sim.stage)
    builder = newton.ModelBuilder()
    builder.replicate(cartpole, copy_count=num_envs)
    model = builder.finalize(device=device)
    return Scene(
        model=model,
        solver=make_solver(model, sim),
        state_0=model.state(),
        state_1=model.state(),
        control=model.control(),
        num_envs=num_envs,
        dofs_per_env=cartpole.joint_dof_count,
        cart_dof=cart_dof,
        pole_dof=pole_dof,
    )
