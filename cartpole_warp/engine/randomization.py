"""Domain randomization (machinery): each env's physical parameters, drawn on the device with the env's own RNG,
written into the Newton model's per-world fields, and the solver told (``notify_model_changed``).

Per joint role (the task's 'cart', 'pole', ...): the mass of the body the role's joint moves (its inertia scaled
with it), a further factor on that body's inertia (another shape), that body's centre of mass along the line from the
joint to it, the joint's viscous damping and its Coulomb friction; per env: the actuator scale, gravity's magnitude
and the action delay. Masses, inertias, centres of mass, damping and gravity are Newton model fields that both
solvers read per world (Featherstone re-derives its spatial inertias in kernels, MuJoCo-Warp recomputes its derived
constants); friction, actuator scale and delay act in the env's own kernels (Featherstone models no joint friction).
Everything here runs in kernels, so it sits inside the captured env step.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np
import warp as wp

from ..settings.config import ConfigError, RandomizationConfig
from ..settings.deprecation import renamed
from .parameters import (
    ACTION_DELAY,
    ACTUATOR_SCALE,
    COM,
    DAMPING,
    FRICTION,
    GRAVITY,
    INERTIA,
    INERTIA_SCALE,
    MASS,
    Quantity,
    parameter_table,
)
from .scene import Scene

if TYPE_CHECKING:
    import newton
    import torch  # imported where used: parsing a command line needs no torch

wp.set_module_options({"enable_backward": False})  # this module's kernels are never differentiated

FRICTION_VELOCITY = wp.constant(0.01)
"""Joint friction is -friction * tanh(velocity / this) (m/s or rad/s): Coulomb friction, smoothed so that it holds
still a joint at rest without chattering at the physics step."""


@dataclass(frozen=True)
class RoleBody:
    """What a role's joint moves, from env 0 of a scene: body and DOF indices inside one env, and the body's authored
    (nominal) mass (kg), inertia about its centre of mass (kg m^2, body frame), centre of mass (m, body frame), the
    unit vector from the joint to it (zero where they coincide) and the joint's axis in the body frame."""

    body: int
    dof: int
    mass: float
    inertia: np.ndarray
    com: np.ndarray
    com_direction: np.ndarray
    com_distance: float
    axis: np.ndarray
    damping: float


def role_bodies(scene: Scene) -> list[RoleBody]:
    """The nominal body of each joint role of ``scene`` (env 0)."""
    m = scene.model
    child, x_c, axis = m.joint_child.numpy(), m.joint_X_c.numpy(), m.joint_axis.numpy()
    mass, inertia, com = m.body_mass.numpy(), m.body_inertia.numpy(), m.body_com.numpy()
    damping = m.joint_damping.numpy()
    out = []
    for joint, dof in zip(scene.role_joints, scene.role_dofs, strict=True):
        body = int(child[joint])
        anchor, rotation = x_c[joint][:3], wp.quat(*x_c[joint][3:])
        lever = com[body] - anchor
        distance = float(np.linalg.norm(lever))
        distance = distance if distance > 1e-9 else 0.0
        out.append(RoleBody(
            body=body, dof=dof, mass=float(mass[body]), inertia=inertia[body].astype(np.float64), com=com[body],
            com_direction=lever / distance if distance else np.zeros(3), com_distance=distance,
            axis=np.array(wp.quat_rotate(rotation, wp.vec3(*axis[dof]))), damping=float(damping[dof])))
    return out


@wp.struct
class Ranges:
    """The config's ranges as the draw kernel takes them: per role (R, 2) low/high and (R,) on flags, per env (2,)."""

    mass_scale: wp.array2d(dtype=float)
    mass_on: wp.array(dtype=wp.int32)
    inertia_scale: wp.array2d(dtype=float)
    inertia_on: wp.array(dtype=wp.int32)
    com_offset: wp.array2d(dtype=float)
    com_on: wp.array(dtype=wp.int32)
    damping: wp.array2d(dtype=float)
    damping_on: wp.array(dtype=wp.int32)
    friction: wp.array2d(dtype=float)
    friction_on: wp.array(dtype=wp.int32)
    actuator_scale: wp.vec2
    actuator_on: int
    gravity: wp.vec2
    gravity_on: int
    max_delay: int


@wp.func
def pick(on: int, u: float, low: float, high: float, keep: float):
    """``low + u (high - low)`` where ``on``, else ``keep``."""
    value = keep
    if on != 0:
        value = low + u * (high - low)
    return value


@wp.struct
class Layout:
    """Where each role's values go in one env's block of the model, and the stage's (nominal) values."""

    bodies_per_env: int
    dofs_per_env: int
    body: wp.array(dtype=wp.int32)
    dof: wp.array(dtype=wp.int32)
    mass: wp.array(dtype=float)
    inertia: wp.array(dtype=wp.mat33)
    com: wp.array(dtype=wp.vec3)
    com_direction: wp.array(dtype=wp.vec3)
    com_distance: wp.array(dtype=float)
    damping: wp.array(dtype=float)
    gravity_direction: wp.vec3
    gravity: float


@wp.struct
class EnvPhysics:
    """Per-env parameters (SI) of a shard's envs: (n, roles) and (n,) arrays."""

    mass: wp.array2d(dtype=float)
    inertia_scale: wp.array2d(dtype=float)
    com: wp.array2d(dtype=float)
    damping: wp.array2d(dtype=float)
    friction: wp.array2d(dtype=float)
    actuator_scale: wp.array(dtype=float)
    gravity: wp.array(dtype=float)
    delay: wp.array(dtype=wp.int32)


@wp.struct
class ModelFields:
    """The Newton model arrays of a shard that hold its envs' parameters."""

    body_mass: wp.array(dtype=float)
    body_inv_mass: wp.array(dtype=float)
    body_inertia: wp.array(dtype=wp.mat33)
    body_inv_inertia: wp.array(dtype=wp.mat33)
    body_com: wp.array(dtype=wp.vec3)
    joint_damping: wp.array(dtype=float)
    gravity: wp.array(dtype=wp.vec3)


@wp.func
def write_env(env: int, layout: Layout, physics: EnvPhysics, model: ModelFields):
    """Env ``env``'s (shard-local) parameters into its world's model fields, inverses included; the inertia about
    the centre of mass scales with the mass and with the inertia scale."""
    for r in range(physics.mass.shape[1]):
        b = env * layout.bodies_per_env + layout.body[r]
        m = physics.mass[env, r]
        inertia = layout.inertia[r] * (m / layout.mass[r] * physics.inertia_scale[env, r])
        model.body_mass[b] = m
        model.body_inv_mass[b] = 1.0 / m
        model.body_inertia[b] = inertia
        model.body_inv_inertia[b] = wp.inverse(inertia)
        model.body_com[b] = layout.com[r] + layout.com_direction[r] * (physics.com[env, r] - layout.com_distance[r])
        model.joint_damping[env * layout.dofs_per_env + layout.dof[r]] = physics.damping[env, r]
    model.gravity[env] = layout.gravity_direction * physics.gravity[env]


@wp.kernel(enable_backward=False)
def draw_physics(everywhere: int, ended: wp.array(dtype=wp.int32), ranges: Ranges, layout: Layout,
                 rng_state: wp.array(dtype=wp.uint32), physics: EnvPhysics, model: ModelFields):
    """New physics for every env (``everywhere``) or where ``ended`` (an end reason) is set, written into the model.
    Every parameter takes its draw from the RNG, randomized or not, so a parameter's value for a seed does not depend
    on which others are randomized."""
    env = wp.tid()
    if everywhere == 0 and ended[env] == 0:
        return
    s = rng_state[env]
    for r in range(physics.mass.shape[1]):
        u = wp.randf(s)
        physics.mass[env, r] = layout.mass[r] * pick(ranges.mass_on[r], u, ranges.mass_scale[r, 0],
                                                     ranges.mass_scale[r, 1], 1.0)
        u = wp.randf(s)
        physics.com[env, r] = layout.com_distance[r] + pick(ranges.com_on[r], u, ranges.com_offset[r, 0],
                                                            ranges.com_offset[r, 1], 0.0)
        u = wp.randf(s)
        physics.damping[env, r] = pick(ranges.damping_on[r], u, ranges.damping[r, 0], ranges.damping[r, 1],
                                       layout.damping[r])
        u = wp.randf(s)
        physics.friction[env, r] = pick(ranges.friction_on[r], u, ranges.friction[r, 0], ranges.friction[r, 1], 0.0)
    u = wp.randf(s)
    physics.actuator_scale[env] = pick(ranges.actuator_on, u, ranges.actuator_scale[0], ranges.actuator_scale[1],
                                       1.0)
    u = wp.randf(s)
    physics.gravity[env] = pick(ranges.gravity_on, u, ranges.gravity[0], ranges.gravity[1], layout.gravity)
    physics.delay[env] = wp.randi(s, 0, ranges.max_delay + 1)
    for r in range(physics.mass.shape[1]):  # after the others: their draws are those of a stream without it
        u = wp.randf(s)
        physics.inertia_scale[env, r] = pick(ranges.inertia_on[r], u, ranges.inertia_scale[r, 0],
                                             ranges.inertia_scale[r, 1], 1.0)
    rng_state[env] = s
    write_env(env, layout, physics, model)


@wp.kernel(enable_backward=False)
def write_model(layout: Layout, physics: EnvPhysics, model: ModelFields):
    """Every env's parameters into the model."""
    write_env(wp.tid(), layout, physics, model)


class PhysicalParams:
    """The per-env physical parameters of a batched env (SI units, persistent (N, roles) and (N,) arrays), their
    draws and their way into each shard's model and solver."""

    def __init__(self, cfg: RandomizationConfig, roles: tuple[str, ...], kinds: list[newton.JointType],
                 scene: Scene, num_envs: int, device: str):
        import newton

        self.cfg, self.roles, self.device = cfg, roles, device
        self.sliders = [kind == newton.JointType.PRISMATIC for kind in kinds]
        """Per role: whether its joint slides (forces in N) rather than turns (torques in N m)."""
        self.table = parameter_table(roles, self.sliders)
        """Every physical parameter: name, quantity, role, unit (``engine.parameters``)."""
        self.bodies = role_bodies(scene)
        self._check_com_offsets()
        gravity = scene.model.gravity.numpy()[0].astype(np.float64)
        self.gravity_m_s2 = float(np.linalg.norm(gravity))
        self.gravity_direction = wp.vec3(*(gravity / self.gravity_m_s2)) if self.gravity_m_s2 else wp.vec3(0.0)
        n, r = num_envs, len(roles)

        def per_role(values) -> wp.array:
            return wp.array(np.tile(np.asarray(values, dtype=np.float32), (n, 1)), dtype=float, device=device)

        self.mass = per_role([b.mass for b in self.bodies])
        self.inertia_scale = per_role(np.ones(r))
        self.com = per_role([b.com_distance for b in self.bodies])
        self.damping = per_role([b.damping for b in self.bodies])
        self.friction = per_role(np.zeros(r))
        self.applies_friction = bool(cfg.joint_friction)
        """Whether the step applies joint friction: where it is randomized, or once ``set`` has given it a value
        (the env then captures its step again)."""
        self.actuator_scale = wp.full(n, 1.0, dtype=float, device=device)
        self.gravity = wp.full(n, self.gravity_m_s2, dtype=float, device=device)
        self.delay = wp.zeros(n, dtype=wp.int32, device=device)
        self.layout = self._make_layout(scene)
        """Where each role's values sit in a scene of this env's stage and env count, and the stage's values."""
        self._ranges = self._make_ranges()
        flags = 0
        if cfg.mass_scale or cfg.inertia_scale or cfg.com_offset_m:
            flags |= newton.ModelFlags.BODY_INERTIAL_PROPERTIES
        if cfg.joint_damping:
            flags |= newton.ModelFlags.JOINT_DOF_FORCE_PROPERTIES
        if cfg.gravity_m_s2 is not None:
            flags |= newton.ModelFlags.MODEL_PROPERTIES
        self.model_flags = flags
        """What a draw changes in the model (and the solver is told of); 0 when only the env's own forces change."""
        self.all_model_flags = (newton.ModelFlags.BODY_INERTIAL_PROPERTIES
                                | newton.ModelFlags.JOINT_DOF_FORCE_PROPERTIES | newton.ModelFlags.MODEL_PROPERTIES)
        """Every model field ``write`` sets."""

    def _check_com_offsets(self):
        """ConfigError where a centre-of-mass offset has no line to move along or would pass the joint."""
        for role, body in zip(self.roles, self.bodies, strict=True):
            if role in self.cfg.com_offset_m:
                low = self.cfg.com_offset_m[role][0]
                if body.com_distance == 0.0:
                    raise ConfigError(f"randomization.com_offset_m.{role}: the {role} body's centre of mass lies on "
                                      "its joint, so there is no line to move it along")
                if body.com_distance + low < 0.0:
                    raise ConfigError(f"randomization.com_offset_m.{role}: low {low:g} would move the centre of mass "
                                      f"past the joint (it sits {body.com_distance:g} m from it)")

    def _make_layout(self, scene: Scene) -> Layout:
        """Where each role's body and joint sit in the model, and their authored values."""
        layout, dev, bodies = Layout(), self.device, self.bodies
        layout.bodies_per_env, layout.dofs_per_env = scene.bodies_per_env, scene.dofs_per_env
        layout.body = wp.array([b.body for b in bodies], dtype=wp.int32, device=dev)
        layout.dof = wp.array([b.dof for b in bodies], dtype=wp.int32, device=dev)
        layout.mass = wp.array([b.mass for b in bodies], dtype=float, device=dev)
        layout.inertia = wp.array([b.inertia for b in bodies], dtype=wp.mat33, device=dev)
        layout.com = wp.array([b.com for b in bodies], dtype=wp.vec3, device=dev)
        layout.com_direction = wp.array([b.com_direction for b in bodies], dtype=wp.vec3, device=dev)
        layout.com_distance = wp.array([b.com_distance for b in bodies], dtype=float, device=dev)
        layout.damping = wp.array([b.damping for b in bodies], dtype=float, device=dev)
        layout.gravity_direction, layout.gravity = self.gravity_direction, self.gravity_m_s2
        return layout

    def _make_ranges(self) -> Ranges:
        cfg, dev = self.cfg, self.device

        def per_role(table: dict) -> tuple[wp.array, wp.array]:
            bounds = [table.get(role, (0.0, 0.0)) for role in self.roles]
            return (wp.array(np.array(bounds, dtype=np.float32).reshape(-1, 2), dtype=float, device=dev),
                    wp.array([int(role in table) for role in self.roles], dtype=wp.int32, device=dev))

        ranges = Ranges()
        ranges.mass_scale, ranges.mass_on = per_role(cfg.mass_scale)
        ranges.inertia_scale, ranges.inertia_on = per_role(cfg.inertia_scale)
        ranges.com_offset, ranges.com_on = per_role(cfg.com_offset_m)
        ranges.damping, ranges.damping_on = per_role(cfg.joint_damping)
        ranges.friction, ranges.friction_on = per_role(cfg.joint_friction)
        ranges.actuator_scale = wp.vec2(*(cfg.actuator_scale or (1.0, 1.0)))
        ranges.actuator_on = int(cfg.actuator_scale is not None)
        ranges.gravity = wp.vec2(*(cfg.gravity_m_s2 or (0.0, 0.0)))
        ranges.gravity_on = int(cfg.gravity_m_s2 is not None)
        ranges.max_delay = cfg.action_delay_steps
        return ranges

    @property
    def drawn(self) -> bool:
        """Whether anything but observation noise is drawn."""
        return self.cfg.on and self.cfg != RandomizationConfig(at=self.cfg.at, obs_noise_std=self.cfg.obs_noise_std)

    def friction_hook(self, shard, actuator_f: wp.array, role_dofs: wp.array) -> Callable[[], None] | None:
        """What runs before each of the shard's solver steps where the step applies joint friction
        (``applies_friction``): the joints' forces = ``actuator_f`` (every env's) less their friction
        (``add_friction``); None where it does not."""
        if not self.applies_friction:
            return None
        s = shard.scene

        def add_joint_friction():
            wp.launch(add_friction, dim=shard.num_envs,
                      inputs=[s.dofs_per_env, role_dofs, shard.rows(actuator_f), shard.rows(self.friction),
                              s.state_0.joint_qd],
                      outputs=[s.control.joint_f], device=self.device)

        return add_joint_friction

    def _shard_structs(self, shard) -> tuple[EnvPhysics, ModelFields]:
        rows, m = shard.rows, shard.scene.model
        physics = EnvPhysics()
        physics.mass, physics.com, physics.damping = rows(self.mass), rows(self.com), rows(self.damping)
        physics.inertia_scale = rows(self.inertia_scale)
        physics.friction, physics.actuator_scale = rows(self.friction), rows(self.actuator_scale)
        physics.gravity, physics.delay = rows(self.gravity), rows(self.delay)
        model = ModelFields()
        model.body_mass, model.body_inv_mass, model.body_com = m.body_mass, m.body_inv_mass, m.body_com
        model.body_inertia, model.body_inv_inertia = m.body_inertia, m.body_inv_inertia
        model.joint_damping, model.gravity = m.joint_damping, m.gravity
        return physics, model

    def draw(self, shard, rng_state: wp.array, ended: wp.array | None):
        """New parameters for the shard's envs where ``ended`` (end reasons) is set, or for all of them (None),
        written into the shard's model; its solver told."""
        physics, model = self._shard_structs(shard)
        wp.launch(draw_physics, dim=shard.num_envs,
                  inputs=[int(ended is None), shard.rows(ended if ended is not None else self.delay), self._ranges,
                          self.layout],
                  outputs=[shard.rows(rng_state), physics, model], device=self.device)
        self._notify(shard, self.model_flags)

    def write(self, shard):
        """Every parameter of the shard's envs into its model; its solver told."""
        physics, model = self._shard_structs(shard)
        wp.launch(write_model, dim=shard.num_envs, inputs=[self.layout, physics], outputs=[model],
                  device=self.device)
        self._notify(shard, self.all_model_flags)

    @staticmethod
    def _notify(shard, flags: int):
        if flags:
            shard.scene.solver.notify_model_changed(flags)

    def values(self) -> dict[str, torch.Tensor]:
        """Each env's parameters in SI units, (N,) tensors named as in ``table``."""
        return self._named(self._arrays())

    def _arrays(self) -> dict[Quantity, torch.Tensor]:
        """The persistent arrays as tensors, by quantity ((N, roles) per role, (N,) per env)."""
        return {MASS: wp.to_torch(self.mass), INERTIA_SCALE: wp.to_torch(self.inertia_scale),
                COM: wp.to_torch(self.com), DAMPING: wp.to_torch(self.damping),
                FRICTION: wp.to_torch(self.friction), ACTUATOR_SCALE: wp.to_torch(self.actuator_scale),
                GRAVITY: wp.to_torch(self.gravity), ACTION_DELAY: wp.to_torch(self.delay)}

    def stage_values(self) -> dict[str, torch.Tensor]:
        """The stage's parameters (what ``values`` gives without randomization), as (1,) tensors."""
        import torch

        def row(values):
            return torch.tensor([values], dtype=torch.float32)

        return self._named({MASS: row([b.mass for b in self.bodies]), INERTIA_SCALE: torch.ones(1, len(self.roles)),
                            COM: row([b.com_distance for b in self.bodies]),
                            DAMPING: row([b.damping for b in self.bodies]), FRICTION: torch.zeros(1, len(self.roles)),
                            ACTUATOR_SCALE: torch.ones(1), GRAVITY: torch.tensor([self.gravity_m_s2]),
                            ACTION_DELAY: torch.zeros(1, dtype=torch.int32)})

    def _named(self, arrays: dict[Quantity, torch.Tensor]) -> dict[str, torch.Tensor]:
        axis_inertia = [float(b.axis @ b.inertia @ b.axis) / b.mass for b in self.bodies]
        out = {}
        for p in self.table:
            if p.quantity is INERTIA:
                out[p.name] = (arrays[MASS][:, p.role_index] * arrays[INERTIA_SCALE][:, p.role_index]
                               * axis_inertia[p.role_index])
            else:
                array = arrays[p.quantity]
                out[p.name] = (array if p.role is None else array[:, p.role_index]).clone()
        return out

    def settable(self) -> list[str]:
        """The names ``set`` takes: those of ``values`` except the derived ones."""
        return [p.name for p in self.table if p.quantity.settable]

    def set(self, values: dict[str, torch.Tensor]) -> bool:
        """Copy (N,) tensors in SI units into the named parameters (ValueError for an unknown name or a value out of
        range); the caller writes them into the model. Whether the step applies joint friction from now on and did
        not before (``applies_friction``)."""
        import torch

        arrays, table = self._arrays(), {p.name: p for p in self.table if p.quantity.settable}
        for name, value in values.items():  # every value checked before any is copied
            if name not in table:
                raise ValueError(f"unknown physical parameter {name!r}; settable: {', '.join(table)}")
            p = table[name]
            low = p.quantity.lowest
            if not torch.isfinite(value.to(torch.float64)).all() or (value < low).any():
                raise ValueError(f"{name}: every value must be finite and >= {low:g}")
            if p.quantity.positive and (value <= low).any():
                raise ValueError(f"{name}: every {p.quantity.key} must be > {low:g}")
            if p.quantity is ACTION_DELAY and (value > self.cfg.action_delay_steps).any():
                raise ValueError(f"action_delay_steps: at most randomization.action_delay_steps="
                                 f"{self.cfg.action_delay_steps} (the action history the env keeps)")
        newly = False
        for name, value in values.items():
            p = table[name]
            (arrays[p.quantity] if p.role is None else arrays[p.quantity][:, p.role_index]).copy_(value)
            newly |= p.quantity is FRICTION and not self.applies_friction and bool((value != 0).any())
        self.applies_friction |= newly
        return newly


@wp.func
def friction_force(friction: float, velocity: float):
    """A joint's Coulomb friction (N or N m) against its velocity (m/s or rad/s), smoothed by FRICTION_VELOCITY."""
    return friction * wp.tanh(velocity / FRICTION_VELOCITY)


@wp.func
def forces_less_friction(env: int, dofs_per_env: int, role_dofs: wp.array(dtype=wp.int32),
                         forces: wp.array2d(dtype=float), friction: wp.array2d(dtype=float),
                         joint_qd: wp.array(dtype=float), joint_f: wp.array(dtype=float)):
    """Env ``env``'s joint_f = its roles' ``forces`` - friction * tanh(velocity / FRICTION_VELOCITY), per role (before
    each physics step; the env's and the differentiable rollout's)."""
    for r in range(friction.shape[1]):
        dof = env * dofs_per_env + role_dofs[r]
        joint_f[dof] = forces[env, r] - friction_force(friction[env, r], joint_qd[dof])


@wp.kernel(enable_backward=False)
def add_friction(dofs_per_env: int, role_dof: wp.array(dtype=wp.int32), actuator_f: wp.array2d(dtype=float),
                 friction: wp.array2d(dtype=float), joint_qd: wp.array(dtype=float), joint_f: wp.array(dtype=float)):
    """``forces_less_friction`` of the actuators' forces in every env."""
    forces_less_friction(wp.tid(), dofs_per_env, role_dof, actuator_f, friction, joint_qd, joint_f)


__getattr__ = renamed(__name__, {"Physics": "PhysicalParams"})
"""The old name, until ``settings.deprecation.REMOVED_IN``."""
