"""The physical parameters' table: each parameter's name, quantity, unit, its section of a preset's randomization and
whether a differentiable rollout takes it. Randomization, the differentiable rollout, ``tools.sysid``,
``tools.gradcheck`` and the robustness grid read names, units and sections here instead of parsing names."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal


@dataclass(frozen=True)
class Quantity:
    """A kind of physical parameter. Per joint role its name is ``<role>_<key>_<unit suffix>`` (the suffix of a
    sliding joint's or of a turning one's unit; none for a factor, unit '1'), per env ``<key>`` (its unit in the
    key)."""

    key: str
    per_role: bool
    slider_unit: str
    """Unit where the role's joint slides (or the env-wide unit), as printed."""
    hinge_unit: str
    """Unit where the role's joint turns."""
    section: str | None
    """The key of ``env.randomization`` that draws it (None: derived, never drawn)."""
    draw: Literal["scale", "offset", "value", "none"]
    """What that section's ranges are: factors on the stage's value, offsets from it (m), or values."""
    settable: bool
    """``env.set_physical_params`` and ``tools.sysid --fit`` take it (derived ones do not)."""
    differentiable: bool
    """A differentiable rollout takes it as a tensor with a gradient."""
    lowest: float
    """Every value is >= this (> for ``positive``)."""
    positive: bool = False

    def name(self, role: str | None, slider: bool) -> str:
        """The parameter's name for ``role`` (None for a per-env quantity)."""
        if not self.per_role:
            return self.key
        unit = self.slider_unit if slider else self.hinge_unit
        if unit == "1":
            return f"{role}_{self.key}"
        return f"{role}_{self.key}_{unit.lower().replace(' ', '_').replace('/', '_').replace('^', '')}"


MASS = Quantity("mass", True, "kg", "kg", "mass_scale", "scale", True, True, 0.0, positive=True)
"""The mass of the body the role's joint moves (its inertia scales with it)."""
COM = Quantity("com", True, "m", "m", "com_offset_m", "offset", True, True, 0.0)
"""That body's centre of mass: its distance from the joint."""
INERTIA = Quantity("inertia", True, "kg m^2", "kg m^2", None, "none", False, False, 0.0)
"""That body's moment of inertia about its centre of mass around the joint's axis (derived: the stage's, times the
mass's factor and the inertia scale)."""
INERTIA_SCALE = Quantity("inertia_scale", True, "1", "1", "inertia_scale", "value", True, True, 0.0, positive=True)
"""A factor on that body's inertia about its centre of mass beyond the mass's (1: the stage's shape): a body whose
shape differs from the stage's, at the same mass."""
DAMPING = Quantity("damping", True, "N s/m", "N m s/rad", "joint_damping", "value", True, True, 0.0)
"""The joint's viscous damping."""
FRICTION = Quantity("friction", True, "N", "N m", "joint_friction", "value", True, True, 0.0)
"""The joint's Coulomb friction."""
ACTUATOR_SCALE = Quantity("actuator_scale", False, "1", "1", "actuator_scale", "value", True, True, 0.0)
"""A factor on the task's joint forces."""
GRAVITY = Quantity("gravity_m_s2", False, "m/s^2", "m/s^2", "gravity_m_s2", "value", True, True, 0.0)
"""Gravity's magnitude."""
ACTION_DELAY = Quantity("action_delay_steps", False, "env steps", "env steps", "action_delay_steps", "value", True,
                        False, 0.0)
"""The age of the action the env applies (an integer; at most ``randomization.action_delay_steps``)."""
QUANTITIES = (MASS, COM, INERTIA, INERTIA_SCALE, DAMPING, FRICTION, ACTUATOR_SCALE, GRAVITY, ACTION_DELAY)
"""Every quantity, in the order of ``env.physical_params()``."""


@dataclass(frozen=True)
class Parameter:
    """One physical parameter of an env: its quantity, for a per-role quantity the joint role (its index in the
    task's roles), and its unit."""

    name: str
    quantity: Quantity
    role: str | None
    role_index: int | None
    unit: str


def parameter_table(roles: tuple[str, ...], sliders: list[bool]) -> tuple[Parameter, ...]:
    """Every physical parameter of a task with these joint roles (``sliders``: per role, whether its joint slides),
    per role first, then per env, in the order of ``env.physical_params()``."""
    table = []
    for index, (role, slider) in enumerate(zip(roles, sliders, strict=True)):
        for quantity in QUANTITIES:
            if quantity.per_role:
                unit = quantity.slider_unit if slider else quantity.hinge_unit
                table.append(Parameter(quantity.name(role, slider), quantity, role, index, unit))
    table += [Parameter(q.key, q, None, None, q.slider_unit) for q in QUANTITIES if not q.per_role]
    return tuple(table)


def of_quantity(table: tuple[Parameter, ...], quantity: Quantity) -> list[Parameter]:
    """The parameters of one quantity, per role in the roles' order."""
    return [p for p in table if p.quantity is quantity]
