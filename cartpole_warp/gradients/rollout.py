"""``DifferentiableRollout``: H env steps of a state task's N envs as torch operations whose gradients reach the
initial joint states, the actions (and through them a policy's parameters) and the physical parameters.

    env = cartpole_warp.tasks.make("cartpole-balance", num_envs=8, sim={"gradients": True})
    rollout = DifferentiableRollout(env, horizon=60)
    params = rollout.stage_params(requires_grad=True)      # {"pole_mass_kg": (N,), ...}: the stage's values
    out = rollout(q0, qd0, policy=actor, params=params)    # or actions=(H, N, num_actions)
    out.rewards.sum().backward()                           # grads on q0, qd0, actor's parameters, params

Each env step is one ``torch.autograd.Function`` around a ``wp.Tape`` of the step's kernels: the task's joint forces
of the clipped action (times ``actuator_scale``), each joint's friction before every physics step, ``decimation``
steps of Newton's SolverFeatherstone, then the task's reward and observation of the state after them. Featherstone
keeps its joint-space mass matrix and the arrays derived from it on the solver and rebuilds them in place every
``sim.mass_matrix_interval`` physics steps, so each build of the horizon has a solver of its own (a tape through one
reused solver reads the last build's arrays backwards); the rest of a step's scratch lives on its states. The bodies'
spatial inertias, which a solver derives from the masses when it is made, are derived again on the tape from the
parameters. With ``sim.capture`` (not 'off') each tape's forward, backward and zeroing are captured as graphs on
first use and replayed after (``CapturedTape``). A result is backpropagated once, before the next call (else
RuntimeError: the tapes and arrays are the rollout's, reused call after call). Ends of episodes are reported as the
env reports them, by the env's rules (the task's, the divergence limit, the time limit counted on from each env's
``episode_steps``), and not applied: a rollout runs its H steps (``Trajectory.end_reason``). The model is the env's
stage, built again with gradients (``sim.gradients``: Newton's kernels with their adjoints); the env's own kernels
stay adjoint-free, and training never builds this.
"""

import dataclasses
import functools
from collections.abc import Callable
from dataclasses import dataclass
from types import SimpleNamespace
from typing import Any

import torch
import warp as wp

from ..engine.env import BatchedEnv
from ..engine.kernels import END_DIVERGED, END_NONE, END_TIME_LIMIT, TaskFunctions, constants_of, kernel_constants
from ..engine.parameters import (
    ACTUATOR_SCALE,
    COM,
    DAMPING,
    FRICTION,
    GRAVITY,
    INERTIA_SCALE,
    MASS,
    Quantity,
    of_quantity,
)
from ..engine.randomization import EnvPhysics, Layout, ModelFields, forces_less_friction, write_env
from ..engine.runtime import collection_paused, load_modules
from ..engine.scene import build_scene, make_solver
from ..engine.step_rules import all_within, clip_actions, role_state, set_role_state, with_time_limit
from ..engine.streams import StreamOrder


@dataclass
class Trajectory:
    """A rollout's tensors: joint positions and velocities (H + 1, N, joints) in the task's role order (m or rad, m/s
    or rad/s), observations (H + 1, N, num_obs), the actions applied (H, N, num_actions, before clipping), the
    rewards (H, N) of each step (0 where the state is beyond ``sim.divergence_limit`` or non-finite, as the env's)
    and the end reason of the state after it (``end_reason``, (H, N) int32, the env's codes: ``END_NONE``, the time
    limit, ``END_DIVERGED`` or the task's; no gradient; the rollout runs on regardless)."""

    q: torch.Tensor
    qd: torch.Tensor
    obs: torch.Tensor
    actions: torch.Tensor
    rewards: torch.Tensor
    end_reason: torch.Tensor

    @property
    def terminated(self) -> torch.Tensor:
        """(H, N) bool: the step ends its episode by the task's rule or the divergence limit (``terminated_buf``)."""
        return (self.end_reason != END_NONE) & (self.end_reason != END_TIME_LIMIT)

    @property
    def truncated(self) -> torch.Tensor:
        """(H, N) bool: the step reaches the time limit (``truncated_buf``)."""
        return self.end_reason == END_TIME_LIMIT

    @property
    def ended(self) -> torch.Tensor:
        """(H, N) bool: the step ends its episode, either way."""
        return self.end_reason != END_NONE


@wp.struct
class StepConstants:
    """What a step's kernels read besides the state: where each joint role's dof sits in an env's (``role_dofs``, of
    ``dofs_per_env``), the joint magnitude beyond which a state has diverged (``sim.divergence_limit``), and for the
    time limit (``max_episode_length`` steps) the steps each env's episode had counted toward it before the rollout
    (``episode_steps``) and this step's index in the horizon (``step``)."""

    role_dofs: wp.array(dtype=int)
    dofs_per_env: int
    divergence_limit: float
    episode_steps: wp.array(dtype=int)
    step: int
    max_episode_length: int


def step_constants(rollout: "DifferentiableRollout", step: int) -> StepConstants:
    """The ``StepConstants`` of step ``step`` of ``rollout``."""
    constants = StepConstants()
    constants.role_dofs, constants.dofs_per_env = rollout.role_dofs, rollout.dofs_per_env
    constants.divergence_limit = float(rollout.sim.divergence_limit)
    constants.episode_steps, constants.step = rollout.episode_steps, step
    constants.max_episode_length = rollout.max_episode_length
    return constants


@wp.func
def row_of(values: wp.array2d(dtype=float), env: int, like: Any):
    """Row ``env`` of ``values`` as a vector of ``like``'s type (a task's ``Joints`` or ``Actions``)."""
    v = type(like)()
    for i in range(len(like)):
        v[i] = values[env, i]
    return v


@functools.cache
def differentiable_kernels(functions: TaskFunctions, config_class: type, num_joints: int, num_actions: int,
                           num_obs: int, name: str) -> Any:
    """A task's kernels for this path, with adjoints, in the Warp module ``name``."""
    fns = functions
    Joints = wp.types.vector(num_joints, float)
    Actions = wp.types.vector(num_actions, float)
    Constants = kernel_constants(config_class)
    kernel = functools.partial(wp.kernel, module=name, enable_backward=True)

    @kernel
    def write_physics(layout: Layout, physics: EnvPhysics, model: ModelFields):
        write_env(wp.tid(), layout, physics, model)

    @kernel
    def set_joints(q: wp.array2d(dtype=float), qd: wp.array2d(dtype=float), constants: StepConstants,
                   joint_q: wp.array(dtype=float), joint_qd: wp.array(dtype=float)):
        env = wp.tid()
        set_role_state(row_of(q, env, Joints()), row_of(qd, env, Joints()), constants.role_dofs,
                       env * constants.dofs_per_env, joint_q, joint_qd)

    @kernel
    def actuate(p: Constants, actions: wp.array2d(dtype=float), actuator_scale: wp.array(dtype=float),
                forces: wp.array2d(dtype=float)):
        env = wp.tid()
        f = fns.joint_forces(clip_actions(row_of(actions, env, Actions())), p, Joints()) * actuator_scale[env]
        for r in range(num_joints):
            forces[env, r] = f[r]

    @kernel
    def add_friction(forces: wp.array2d(dtype=float), friction: wp.array2d(dtype=float), constants: StepConstants,
                     joint_qd: wp.array(dtype=float), joint_f: wp.array(dtype=float)):
        forces_less_friction(wp.tid(), constants.dofs_per_env, constants.role_dofs, forces, friction, joint_qd,
                             joint_f)

    @kernel
    def read_step(p: Constants, constants: StepConstants, joint_q: wp.array(dtype=float),
                  joint_qd: wp.array(dtype=float), actions: wp.array2d(dtype=float),
                  q_out: wp.array2d(dtype=float), qd_out: wp.array2d(dtype=float), obs: wp.array2d(dtype=float),
                  rewards: wp.array(dtype=float), end_reason: wp.array(dtype=wp.int32)):
        env = wp.tid()
        q, qd = role_state(joint_q, joint_qd, constants.role_dofs, env * constants.dofs_per_env, Joints())
        for r in range(num_joints):
            q_out[env, r] = q[r]
            qd_out[env, r] = qd[r]
        reward, end = fns.reward_and_end(q, qd, clip_actions(row_of(actions, env, Actions())), p)
        within = all_within(q, qd, constants.divergence_limit)  # as the env judges a state
        rewards[env] = wp.where(within, reward, 0.0)
        if end == END_NONE and not within:
            end = END_DIVERGED
        count = constants.episode_steps[env] + constants.step + 1
        end_reason[env] = with_time_limit(end, count, constants.max_episode_length)
        o = fns.observe(q, qd, p)
        for i in range(num_obs):
            obs[env, i] = o[i]

    @kernel
    def observe(p: Constants, q: wp.array2d(dtype=float), qd: wp.array2d(dtype=float), obs: wp.array2d(dtype=float)):
        env = wp.tid()
        o = fns.observe(row_of(q, env, Joints()), row_of(qd, env, Joints()), p)
        for i in range(num_obs):
            obs[env, i] = o[i]

    return SimpleNamespace(write_physics=write_physics, set_joints=set_joints, actuate=actuate,
                           add_friction=add_friction, read_step=read_step, observe=observe)


def zeros(shape: tuple, device: str, dtype=float) -> wp.array:
    return wp.zeros(shape, dtype=dtype, device=device, requires_grad=True)


class CapturedTape:
    """A ``wp.Tape`` of ``launch()``'s kernels. The first forward runs op by op (the solver allocates its scratch
    then); with ``capture`` the second is recorded on a new tape inside a graph capture, and from then on the forward,
    the tape's backward and its zeroing of the gradients are each captured on first use and replayed (the launches'
    arrays stay put, so the graphs stay valid): Warp's Python per launch and per adjoint is most of a step's time
    otherwise, on a CPU as on a GPU. Without ``capture`` every forward records a new tape."""

    def __init__(self, device: str, launch: Callable[[], None], capture: bool):
        self.device, self.launch, self.capture = device, launch, capture
        self.tape: wp.Tape | None = None
        self.graphs: dict[str, Any] = {}

    def _replay(self, name: str, work: Callable[[], None]):
        if name not in self.graphs:
            with collection_paused(), wp.ScopedCapture(device=self.device) as captured:
                work()
            self.graphs[name] = captured.graph
        wp.capture_launch(self.graphs[name])

    def _record(self):
        with self.tape:
            self.launch()

    def forward(self):
        if "forward" in self.graphs:
            wp.capture_launch(self.graphs["forward"])
            return
        warmed = self.tape is not None
        self.tape = wp.Tape()
        if self.capture and warmed:
            self._replay("forward", self._record)
        else:
            self._record()

    def backward(self):
        if "forward" in self.graphs:
            self._replay("backward", self.tape.backward)
        else:
            self.tape.backward()

    def zero(self):
        """Zero the gradients the tape's backward adds to (captured once a backward has named them all)."""
        if "backward" in self.graphs:
            self._replay("zero", self.tape.zero)
        elif self.tape is not None:
            self.tape.zero()


class EnvStep:
    """The arrays, states and solvers of one env step of the horizon (its ``decimation`` physics steps)."""

    def __init__(self, rollout: "DifferentiableRollout", index: int):
        r, n, dev = rollout, rollout.num_envs, rollout.device
        j, a = r.num_joints, r.num_actions
        self.q, self.qd, self.actions = zeros((n, j), dev), zeros((n, j), dev), zeros((n, a), dev)
        self.forces = zeros((n, j), dev)
        self.q_out, self.qd_out = zeros((n, j), dev), zeros((n, j), dev)
        self.obs, self.rewards = zeros((n, r.num_obs), dev), zeros((n,), dev)
        self.end_reason = wp.zeros(n, dtype=wp.int32, device=dev)
        self.constants = step_constants(rollout, index)
        model = r.model
        self.states = [model.state(requires_grad=True) for _ in range(r.decimation + 1)]
        self.controls = [model.control() for _ in range(r.decimation)]
        # one solver per mass matrix the env's solver builds in a step (every sim.mass_matrix_interval physics
        # steps); the physics steps between read it, as the env's do. The rest of the step's scratch lives on the
        # states (Featherstone's choice when the states take gradients).
        self.solvers = [make_solver(model, r.sim, tiles=False) for _ in range(r.decimation // r.mass_matrix_interval)]
        for solver in self.solvers:
            if solver._has_joint_mimics or not hasattr(solver, "_step"):
                raise ValueError("a differentiable rollout needs Featherstone without mimic joints "
                                 "(Newton 1.8's solver, whose step counter picks when the mass matrix is built)")
            solver.body_I_m, solver.body_X_com = r.inertia_solver.body_I_m, r.inertia_solver.body_X_com
        self.tape = CapturedTape(dev, functools.partial(self.launch, r), r.capture)
        """The step: ``q``, ``qd``, ``actions`` in; ``q_out``, ``qd_out``, ``obs``, ``rewards``, ``end_reason``
        out."""

    def launch(self, rollout: "DifferentiableRollout"):
        r, k, dev, n = rollout, rollout.kernels, rollout.device, rollout.num_envs
        first = self.states[0]
        wp.launch(k.set_joints, n, inputs=[self.q, self.qd, self.constants],
                  outputs=[first.joint_q, first.joint_qd], device=dev)
        wp.launch(k.actuate, n, inputs=[r.task_constants, self.actions, r.actuator_scale], outputs=[self.forces],
                  device=dev)
        for i in range(r.decimation):
            state, control = self.states[i], self.controls[i]
            wp.launch(k.add_friction, n, inputs=[self.forces, r.friction, self.constants, state.joint_qd],
                      outputs=[control.joint_f], device=dev)
            solver = self.solvers[i // r.mass_matrix_interval]
            solver._step = i % r.mass_matrix_interval  # 0: build the mass matrix, else read the one built
            solver.step(state, self.states[i + 1], control, None, r.physics_dt)
        last = self.states[-1]
        wp.launch(k.read_step, n, inputs=[r.task_constants, self.constants, last.joint_q, last.joint_qd, self.actions],
                  outputs=[self.q_out, self.qd_out, self.obs, self.rewards, self.end_reason], device=dev)


def as_warp(array: wp.array, tensor: torch.Tensor):
    wp.to_torch(array).copy_(tensor.detach().to(torch.float32))


def grad_of(array: wp.array) -> torch.Tensor:
    return wp.to_torch(array.grad).clone()


def check_backward(ctx):
    """RuntimeError where this backward cannot be right: the rollout has run again since (its arrays and tapes hold
    the newer call), or this call was backpropagated already (its tapes add to the gradients they left)."""
    if ctx.call != ctx.rollout.calls:
        raise RuntimeError("this rollout's result is stale: the DifferentiableRollout has run again since; call "
                           "backward before the next call")
    if getattr(ctx, "done", False):
        raise RuntimeError("a DifferentiableRollout's result can be backpropagated once (retain_graph is not "
                           "supported): run the rollout again")
    ctx.done = True


class PhysicsFunction(torch.autograd.Function):
    """The physical parameters into the model and the spatial inertias derived from them, on a tape; its output, a
    token, is an input of every step, so that its backward runs after theirs (whose tapes add to the model's grads)."""

    @staticmethod
    def forward(ctx, rollout, mass, inertia_scale, com, damping, friction, actuator_scale, gravity):
        ctx.rollout, ctx.call = rollout, rollout.calls
        for array, tensor in zip(rollout.physics_arrays, (mass, inertia_scale, com, damping, friction, actuator_scale,
                                                          gravity)):
            as_warp(array, tensor)
        with rollout.order:
            rollout.physics_tape.forward()
        return torch.zeros((), device=mass.device, requires_grad=True)

    @staticmethod
    def backward(ctx, _token_grad):
        check_backward(ctx)
        rollout = ctx.rollout
        with rollout.order:
            rollout.physics_tape.backward()
        return (None, *(grad_of(array) for array in rollout.physics_arrays))


class StepFunction(torch.autograd.Function):
    """One ``EnvStep``: (token, q, qd, actions) -> (q', qd', obs', reward)."""

    @staticmethod
    def forward(ctx, rollout, step, token, q, qd, actions):
        ctx.rollout, ctx.step, ctx.call = rollout, step, rollout.calls
        as_warp(step.q, q)
        as_warp(step.qd, qd)
        as_warp(step.actions, actions)
        with rollout.order:
            step.tape.forward()
        return tuple(wp.to_torch(a).clone() for a in (step.q_out, step.qd_out, step.obs, step.rewards))

    @staticmethod
    def backward(ctx, q_grad, qd_grad, obs_grad, reward_grad):
        check_backward(ctx)
        step = ctx.step
        for array, grad in zip((step.q_out, step.qd_out, step.obs, step.rewards), (q_grad, qd_grad, obs_grad,
                                                                                  reward_grad)):
            wp.to_torch(array.grad).copy_(grad)
        with ctx.rollout.order:
            step.tape.backward()
        token_grad = torch.zeros((), device=q_grad.device)
        return None, None, token_grad, grad_of(step.q), grad_of(step.qd), grad_of(step.actions)


class ObserveFunction(torch.autograd.Function):
    """The task's observation of joint states (N, joints) -> (N, num_obs)."""

    @staticmethod
    def forward(ctx, rollout, q, qd):
        ctx.rollout, ctx.call = rollout, rollout.calls
        as_warp(rollout.q0, q)
        as_warp(rollout.qd0, qd)
        with rollout.order:
            rollout.observe_tape.forward()
        return wp.to_torch(rollout.obs0).clone()

    @staticmethod
    def backward(ctx, obs_grad):
        check_backward(ctx)
        rollout = ctx.rollout
        wp.to_torch(rollout.obs0.grad).copy_(obs_grad)
        with rollout.order:
            rollout.observe_tape.backward()
        return None, grad_of(rollout.q0), grad_of(rollout.qd0)


DENSE_ONLY = "its gradients are checked against central differences on that path alone"
"""Why a rollout steps SolverFeatherstone's dense path whatever ``sim.tile_gemm`` says."""


def check_rollout(env: BatchedEnv, horizon: int):
    """ValueError where ``env`` cannot be rolled out differentiably for ``horizon`` env steps."""
    cfg = env.cfg
    if cfg.sim.solver != "featherstone" or not cfg.sim.gradients:
        raise ValueError("a differentiable rollout needs an env built with SolverFeatherstone and "
                         "sim={'gradients': True} (Newton's kernels with their adjoints); got "
                         f"sim.solver={cfg.sim.solver!r}, sim.gradients={cfg.sim.gradients}")
    if cfg.sim.tile_gemm == "on":
        raise ValueError(f"a differentiable rollout keeps SolverFeatherstone's dense path ({DENSE_ONLY}); got "
                         "sim.tile_gemm='on'")
    if env.sees_images:
        raise ValueError("a differentiable rollout runs state tasks (the renderer has no adjoint); "
                         f"{type(env).__name__} observes camera frames")
    if horizon < 1:
        raise ValueError(f"horizon must be >= 1 env step, got {horizon}")


class DifferentiableRollout:
    """``horizon`` env steps of ``env``'s task for its ``num_envs`` envs, differentiable (module docstring). ``env``:
    a state task's env on the CPU or a GPU, built with ``sim={"gradients": True}`` and SolverFeatherstone; only its
    config, task functions and stage are used (its own buffers are not touched)."""

    def __init__(self, env: BatchedEnv, horizon: int):
        check_rollout(env, horizon)
        cfg = env.cfg
        self.num_envs, self.device, self.horizon = env.num_envs, env.device, horizon
        self.roles = env.joint_roles
        self.num_joints, self.num_actions, self.num_obs = len(self.roles), env.num_actions, env.num_obs
        self.decimation, self.physics_dt = cfg.sim.decimation, cfg.sim.physics_dt
        self.mass_matrix_interval = cfg.sim.mass_matrix_interval
        self.sim = dataclasses.replace(cfg.sim, tile_gemm="off")
        """The env's physics settings on SolverFeatherstone's dense path (``DENSE_ONLY``)."""
        self.order = StreamOrder(self.device)
        """Warp's work after torch's pending work on entry, torch's after Warp's on exit (their CUDA streams)."""
        self.calls = 0
        """Calls so far: a result's backward must belong to the last one."""
        self.kernels = differentiable_kernels(env.functions, env.config_class, self.num_joints, self.num_actions,
                                              self.num_obs, f"{type(env).__module__}.{type(env).__qualname__}.grad")
        load_modules([self.kernels.write_physics.module], self.device, "the differentiable rollout (with adjoints)")
        self.task_constants = constants_of(env.config_class, cfg.task)
        scene = build_scene(self.num_envs, self.device, self.sim, env.stage_path, env.joints(cfg.task),
                            requires_grad=True)
        self.model, self.dofs_per_env = scene.model, scene.dofs_per_env
        self.held = torch.tensor([role in cfg.sim.held_joints for role in self.roles], device=self.device)
        """Per role: whether ``sim.held_joints`` holds it (its velocity zeroed at the start)."""
        self.role_dofs = wp.array(scene.role_dofs, dtype=int, device=self.device)
        self.max_episode_length = int(cfg.max_episode_length)
        self.episode_steps = wp.zeros(self.num_envs, dtype=int, device=self.device)
        """Each env's steps toward the time limit before the call (``__call__``'s ``episode_steps``)."""
        self.inertia_solver = scene.solver
        self.physical = env.physics
        self.layout = env.physics.layout  # the same stage and env count: the same places
        self._make_physics()
        n, roles, dev = self.num_envs, self.num_joints, self.device
        self.q0, self.qd0, self.obs0 = zeros((n, roles), dev), zeros((n, roles), dev), zeros((n, self.num_obs), dev)
        self.capture = cfg.sim.capture != "off"
        self.steps = [EnvStep(self, t) for t in range(horizon)]
        self.physics_tape = CapturedTape(self.device, self._write_physics, self.capture)
        self.observe_tape = CapturedTape(self.device, self._observe, self.capture)
        self.parameter_table = env.physics.table
        self.parameter_names = [p.name for p in self.parameter_table if p.quantity.differentiable]
        """The physical parameters a rollout takes (``stage_params``' names; ``engine.parameters``' differentiable
        ones): per joint role its body's mass, inertia scale and centre of mass, the joint's damping and friction;
        the actuator scale and gravity."""

    def _make_physics(self):
        """The physical parameters' arrays (with gradients), their struct for the kernels, and the model's fields
        that they are written into."""
        n, roles, dev = self.num_envs, self.num_joints, self.device
        self.mass, self.inertia_scale, self.com, self.damping, self.friction = (zeros((n, roles), dev)
                                                                                for _ in range(5))
        self.actuator_scale, self.gravity = zeros((n,), dev), zeros((n,), dev)
        self.physics_arrays = (self.mass, self.inertia_scale, self.com, self.damping, self.friction,
                               self.actuator_scale, self.gravity)
        self.env_physics = EnvPhysics()
        p = self.env_physics
        p.mass, p.inertia_scale, p.com = self.mass, self.inertia_scale, self.com
        p.damping, p.friction = self.damping, self.friction
        p.actuator_scale, p.gravity, p.delay = self.actuator_scale, self.gravity, wp.zeros(n, dtype=wp.int32,
                                                                                           device=dev)
        m, fields = self.model, ModelFields()
        fields.body_mass, fields.body_inv_mass, fields.body_com = m.body_mass, m.body_inv_mass, m.body_com
        fields.body_inertia, fields.body_inv_inertia = m.body_inertia, m.body_inv_inertia
        fields.joint_damping, fields.gravity = m.joint_damping, m.gravity
        self.model_fields = fields

    def _write_physics(self):
        """The physical parameters into the model, and the spatial inertias derived from them."""
        wp.launch(self.kernels.write_physics, self.num_envs, inputs=[self.layout, self.env_physics],
                  outputs=[self.model_fields], device=self.device)
        self.inertia_solver._update_body_inertial_buffers()

    def _observe(self):
        wp.launch(self.kernels.observe, self.num_envs, inputs=[self.task_constants, self.q0, self.qd0],
                  outputs=[self.obs0], device=self.device)

    def stage_params(self, requires_grad: bool = False) -> dict[str, torch.Tensor]:
        """The stage's physical parameters, (N,) float32 tensors on the device, by name."""
        values = self.physical.stage_values()
        return {name: values[name].to(self.device, torch.float32).expand(self.num_envs).clone()
                .requires_grad_(requires_grad) for name in self.parameter_names}

    def _physics_tensors(self, params: dict[str, torch.Tensor]) -> list[torch.Tensor]:
        unknown = sorted(set(params) - set(self.parameter_names))
        if unknown:
            raise ValueError(f"unknown physical parameters {unknown}; a rollout takes {self.parameter_names}")
        full = self.stage_params() | params

        def per_role(quantity: Quantity) -> torch.Tensor:
            return torch.stack([full[p.name] for p in of_quantity(self.parameter_table, quantity)], dim=1)

        return [per_role(MASS), per_role(INERTIA_SCALE), per_role(COM), per_role(DAMPING), per_role(FRICTION),
                full[ACTUATOR_SCALE.key], full[GRAVITY.key]]

    def __call__(self, q0: torch.Tensor, qd0: torch.Tensor, actions: torch.Tensor | None = None,
                 policy: Callable[[torch.Tensor], torch.Tensor] | None = None,
                 params: dict[str, torch.Tensor] | None = None, episode_steps: torch.Tensor | None = None
                 ) -> Trajectory:
        """Run the horizon from joint states ``q0``, ``qd0`` (N, joints) under ``actions`` (H, N, num_actions) or
        ``policy(obs) -> actions`` with ``params`` (by name, (N,) each; the stage's where not given); each env's episode
        had counted ``episode_steps`` (N,) toward the time limit before (the env's ``episode_length_buf``; default 0).
        Backward through the result before the next call: each step's tape and arrays are reused."""
        if (actions is None) == (policy is None):
            raise ValueError("give actions (H, N, num_actions) or a policy, not both")
        self.calls += 1
        with self.order:
            for tape in (self.physics_tape, self.observe_tape, *(step.tape for step in self.steps)):
                tape.zero()
            wp.to_torch(self.episode_steps).copy_(0 if episode_steps is None else episode_steps)
        token = PhysicsFunction.apply(self, *self._physics_tensors(params or {}))
        q, qd = q0, torch.where(self.held, 0.0, qd0)  # as the env zeroes a held joint's velocity
        obs = ObserveFunction.apply(self, q, qd)
        qs, qds, observations, applied, rewards, ends = [q], [qd], [obs], [], [], []
        for t, step in enumerate(self.steps):
            action = actions[t] if actions is not None else policy(obs)
            q, qd, obs, reward = StepFunction.apply(self, step, token, q, qd, action)
            qs.append(q), qds.append(qd), observations.append(obs), applied.append(action), rewards.append(reward)
            ends.append(wp.to_torch(step.end_reason).clone())
        return Trajectory(torch.stack(qs), torch.stack(qds), torch.stack(observations), torch.stack(applied),
                          torch.stack(rewards), torch.stack(ends))
