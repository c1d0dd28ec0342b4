"""USD stage -> Newton model replicated ``num_envs`` times -> solver (machinery: it knows joints, not robots).

Build order (as in Newton's examples): ModelBuilder -> add_usd -> replicate -> finalize -> solver ->
state_0 / state_1 / control. The task names the joints it drives or reads (``JointRole``: a role, the joint's name
in the stage, its type); they are found by name, and every other joint must be fixed. Everything physical (masses,
lengths, inertias, limits, gravity) comes from the stage.

Newton is imported where a scene is built, not with this module: its import takes seconds, and the command line, the
task registry and the configs do without it.
"""

from __future__ import annotations

import importlib
import sys
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import warp as wp

from ..settings.config import BYTES_PER_ENV, ConfigError, SimConfig, StageError
from .runtime import init_warp

if TYPE_CHECKING:
    import newton

SHARDABLE_SOLVERS = ("featherstone",)
"""Solvers whose CPU scenes can step in parallel threads; mujoco-warp's tile kernels share one CPU arena, so
concurrent replays of MuJoCo scenes abort (and so do SolverFeatherstone's on its tile path: ``shardable``)."""


def shardable(sim: SimConfig, device: str) -> bool:
    """Whether ``sim``'s CPU scenes can step in parallel threads: a solver of SHARDABLE_SOLVERS, without Warp's tile
    kernels (their CPU arena is one for every thread)."""
    return sim.solver in SHARDABLE_SOLVERS and not sim.tiles(device)


FEATHERSTONE_MODULE = "newton._src.solvers.featherstone.kernels"
"""The Warp module of SolverFeatherstone's kernels."""


@dataclass(frozen=True)
class JointRole:
    """A joint the task drives or reads: ``role`` (e.g. 'cart'), the joint's ``name`` in the stage (or its full prim
    path where the name repeats), its ``kind`` and the config ``key`` that sets the name (for error messages)."""

    role: str
    name: str
    kind: newton.JointType
    key: str


@dataclass
class Scene:
    """A finalized Newton model of ``num_envs`` robots (one world each) and the solver that steps it."""

    model: newton.Model
    solver: newton.solvers.SolverBase
    state_0: newton.State
    state_1: newton.State
    control: newton.Control
    num_envs: int
    dofs_per_env: int
    """Joint coordinates (= DOFs, all movable joints being 1-DOF) of one robot."""
    bodies_per_env: int
    role_dofs: list[int]
    """For each joint role, in the task's order, the index of its DOF inside one env's block of joint_q / joint_qd /
    joint_f."""
    role_joints: list[int]
    """For each joint role, the index of its joint in env 0 (the same inside every env's block)."""
    held_dofs: wp.array | None = None
    """The DOFs (inside one env's block) of the held joints (``sim.held_joints``), or None."""

    def simulate(self, physics_dt: float, steps: int, before_step: Callable[[], None] | None = None):
        """Advance every env ``steps`` physics steps, calling ``before_step`` before each (the held joints' velocities
        zeroed first); the result ends in ``state_0`` (graph-capturable)."""
        if self.held_dofs is not None:
            wp.launch(hold_still, dim=(self.num_envs, self.held_dofs.shape[0]),
                      inputs=[self.dofs_per_env, self.held_dofs], outputs=[self.state_0.joint_qd],
                      device=self.model.device)
        for _ in range(steps):
            if before_step is not None:
                before_step()
            self.solver.step(self.state_0, self.state_1, self.control, None, physics_dt)
            self.state_0, self.state_1 = self.state_1, self.state_0
        if steps % 2 == 1:
            self.state_1.assign(self.state_0)
            self.state_0, self.state_1 = self.state_1, self.state_0


@wp.kernel(enable_backward=False)
def hold_still(dofs_per_env: int, held_dofs: wp.array(dtype=int), joint_qd: wp.array(dtype=float)):
    """Zero the velocity of each env's held DOFs (one thread per env and held DOF)."""
    env, k = wp.tid()
    joint_qd[env * dofs_per_env + held_dofs[k]] = 0.0


def hold(robot: newton.ModelBuilder, role_joints: list[int], joints: list[JointRole], held: list[str]) -> list[int]:
    """Make the bodies of the ``held`` roles' joints kinematic in ``robot``; their joints' DOFs (ConfigError for a
    role the task does not have)."""
    import newton

    roles = [joint.role for joint in joints]
    unknown = [role for role in held if role not in roles]
    if unknown:
        raise ConfigError(f"sim.held_joints: unknown joint roles {unknown}; this task's roles: {', '.join(roles)}")
    dofs = []
    for role in held:
        joint = role_joints[roles.index(role)]
        robot.body_flags[robot.joint_child[joint]] = int(newton.BodyFlags.KINEMATIC)
        dofs.append(robot.joint_qd_start[joint])
    return dofs


def check_units(path: Path):
    """StageError unless the stage is authored in metres and kilograms (Newton's importer assumes both and only
    warns otherwise; the task's limits are in metres and radians)."""
    from pxr import Usd, UsdGeom, UsdPhysics

    try:
        stage = Usd.Stage.Open(str(path))
    except Exception as err:  # usd-core raises Tf.ErrorException for unreadable files
        raise StageError(f"cannot load USD stage {path}: {' '.join(str(err).split())}") from None
    meters, kilograms = UsdGeom.GetStageMetersPerUnit(stage), UsdPhysics.GetStageKilogramsPerUnit(stage)
    if abs(meters - 1.0) > 1e-9 or abs(kilograms - 1.0) > 1e-9:
        raise StageError(f"stage {path} is authored in metersPerUnit={meters:g}, kilogramsPerUnit={kilograms:g}; "
                         "cartpole_warp simulates stages in metres and kilograms (both 1): rescale the stage")


def pick_joint(labels: list[str], joint: JointRole, path: Path) -> int:
    """Index of the joint whose prim path is ``joint.name`` or ends in ``/name``; StageError naming the stage file and
    the candidates when none or several match."""
    name = joint.name
    found = [i for i, label in enumerate(labels) if label == name or label.endswith("/" + name)]
    if len(found) == 1:
        return found[0]
    if not found:
        raise StageError(f"stage {path}: no joint named {name!r} for the {joint.role} joint (set {joint.key}); "
                         f"its joints: {', '.join(labels) or 'none'}")
    raise StageError(f"stage {path}: {len(found)} joints match {name!r} for the {joint.role} joint: "
                     f"{', '.join(labels[i] for i in found)}; give {joint.key} the full prim path")


def load_robot(stage_path: Path, joints: list[JointRole]) -> tuple[newton.ModelBuilder, list[int]]:
    """One robot from the stage: (builder, the joint of each joint role). Each role's joint must be of its kind, every
    other joint fixed."""
    import newton

    path = Path(stage_path)
    if not path.is_file():
        raise StageError(f"USD stage not found: {path}")
    check_units(path)
    builder = newton.ModelBuilder()
    newton.solvers.SolverMuJoCo.register_custom_attributes(builder)
    try:
        builder.add_usd(str(path), enable_self_collisions=False, collapse_fixed_joints=True)
    except Exception as err:  # usd-core and the importer raise many types; name the file once
        raise StageError(f"cannot load USD stage {path}: {type(err).__name__}: {err}") from err
    labels = list(builder.joint_label)
    kinds = [newton.JointType(kind) for kind in builder.joint_type]
    found = [pick_joint(labels, joint, path) for joint in joints]
    for index, joint in zip(found, joints, strict=True):
        if kinds[index] != joint.kind:
            raise StageError(f"the {joint.role} joint {labels[index]} of {path} is {kinds[index].name.lower()}; it "
                             f"must be {joint.kind.name.lower()}")
    others = [f"{label} ({kind.name.lower()})" for i, (label, kind) in enumerate(zip(labels, kinds, strict=True))
              if i not in found and kind != newton.JointType.FIXED]
    if others:
        roles = " and ".join(joint.role for joint in joints)
        raise StageError(f"stage {path}: only the {roles} joints may move, but it also has {', '.join(others)}")
    return builder, found


def make_solver(model: newton.Model, sim: SimConfig, tiles: bool) -> newton.solvers.SolverBase:
    """The configured solver, set up for frictionless, undamped joints without contacts; SolverFeatherstone on its
    tile path where ``tiles``. Its tile kernels (a Warp module per articulation size, made here) compile with
    adjoints only where ``sim.gradients``: Warp gives a module the global ``enable_backward`` when it is made, so that
    setting is changed for the solver's construction alone."""
    import newton

    if sim.solver != "featherstone":
        return newton.solvers.SolverMuJoCo(model, disable_contacts=True)
    backward = wp.config.enable_backward
    wp.config.enable_backward = sim.gradients if tiles else backward
    try:
        return newton.solvers.SolverFeatherstone(model, angular_damping=0.0, use_tile_gemm=tiles,
                                                 update_mass_matrix_interval=sim.mass_matrix_interval)
    finally:
        wp.config.enable_backward = backward


def model_modules() -> list[wp.Module]:
    """The Warp modules of Newton that ``ModelBuilder.finalize`` loads (Newton 1.8, as Warp's module log of a build
    shows them): the inertia checks and the shape BVH."""
    from newton._src.geometry import inertia

    return [wp.get_module("newton._src.geometry.bvh"), inertia.validate_and_correct_inertia_kernel.module,
            inertia.compute_body_inverses_kernel.module]


def solver_modules(solver: str) -> list[wp.Module]:
    """The Warp modules of ``solver``: SolverFeatherstone's one module, or every module of mujoco-warp and Newton's
    MuJoCo solver (each loaded only when one of its kernels launches)."""
    if solver == "featherstone":
        return [wp.get_module(importlib.import_module(FEATHERSTONE_MODULE).__name__)]  # its kernels registered
    import mujoco_warp  # noqa: F401 (its modules are listed by name below)

    prefixes = ("mujoco_warp.", "newton._src.solvers.mujoco.")
    return [wp.get_module(name) for name in list(sys.modules) if name.startswith(prefixes)]


def preloadable_modules(solver: str) -> list[wp.Module]:
    """The Newton modules that a build with ``solver`` loads whole, to compile in parallel before it (after
    ``set_gradients``: their options must be those the build loads them with); mujoco-warp's load as they launch."""
    return model_modules() + (solver_modules(solver) if solver == "featherstone" else [])


def set_gradients(solver: str, gradients: bool):
    """Whether Newton's modules for ``solver`` compile their adjoint code: Warp's ``enable_backward`` option set on
    those modules alone (not globally), where it differs. SolverFeatherstone's own options on its module (its
    ``deterministic`` mode, as Newton 1.8 sets them when the solver is made) are set now too, so that a module loaded
    before the solver exists is the one the solver steps with."""
    for module in model_modules() + solver_modules(solver):
        options = {"enable_backward": gradients}
        if module.name == FEATHERSTONE_MODULE:
            options |= {"deterministic": wp.config.deterministic, "deterministic_max_records": 0}
        if any(module.options.get(name) != value for name, value in options.items()):
            wp.set_module_options(options, module=module)


def build_scene(num_envs: int, device: str, sim: SimConfig, stage: Path, joints: list[JointRole],
                requires_grad: bool = False) -> Scene:
    """Load the stage, replicate it ``num_envs`` times into separate worlds, finalize (with gradient arrays where
    ``requires_grad``) and make the solver."""
    import newton

    init_warp()
    set_gradients(sim.solver, sim.gradients)
    robot, role_joints = load_robot(stage, joints)
    held_dofs = hold(robot, role_joints, joints, sim.held_joints)
    builder = newton.ModelBuilder()
    try:
        builder.replicate(robot, copy_count=num_envs)
        model = builder.finalize(device=device, requires_grad=requires_grad)
    except MemoryError:
        raise ConfigError(f"not enough memory for {num_envs:,} envs (about {num_envs * BYTES_PER_ENV / 1e9:,.1f} GB "
                          "while building them): use fewer") from None
    scene = Scene(
        model=model,
        solver=make_solver(model, sim, sim.tiles(str(model.device))),
        state_0=model.state(),
        state_1=model.state(),
        control=model.control(),
        num_envs=num_envs,
        dofs_per_env=robot.joint_dof_count,
        bodies_per_env=robot.body_count,
        role_dofs=[robot.joint_qd_start[index] for index in role_joints],
        role_joints=role_joints,
        held_dofs=wp.array(held_dofs, dtype=int, device=model.device) if held_dofs else None,
    )
    if model.device.is_cuda:
        # The solver allocates its scratch arrays on its first step. Inside a CUDA graph capture that memory would be
        # the graph's, unusable by other graphs or launches until the graph has replayed (an illegal memory access):
        # take the first steps here, two whole env steps: the mass-matrix schedule keeps its phase, and an even count
        # leaves the states unswapped (a state that takes gradients holds scratch the other lacks: no assign).
        scene.simulate(sim.physics_dt, 2 * sim.decimation)
    return scene
