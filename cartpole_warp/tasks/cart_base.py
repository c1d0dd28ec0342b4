"""What the cart tasks share (no task itself): a cart on a prismatic joint pushed by the action, and revolute poles
above it (role 'pole' hinged to the cart, further ones to the pole below). A task's config names each joint
(``<role>_joint``) and scales the cart force."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import warp as wp

from ..engine.env import BatchedEnv
from ..engine.scene import JointRole
from ..settings.config import Name, NonNegative, TaskConfig


@dataclass
class CartpoleConfig(TaskConfig):
    """Settings of every cart task: the joints of the cart and of the pole hinged to it, and the cart force."""

    cart_joint: Name = "cartJoint"
    """The stage's prismatic joint that moves the cart: its name, or its full prim path where the name repeats."""
    pole_joint: Name = "poleJoint"
    """The stage's revolute joint of the pole on the cart: its name, or its full prim path where the name repeats."""
    max_push_effort_n: NonNegative = 400.0
    """Cart force (N) for action 1; actions are clipped to [-1, 1] first."""


@wp.func
def push_cart(action: Any, p: Any, forces: Any):
    """``TaskFunctions.joint_forces`` of every cart task: max_push_effort_n * action on the cart (the first joint role),
    nothing on the poles, whatever their number (generic over the task's params struct and joint vector)."""
    f = forces
    f[0] = p.max_push_effort_n * action[0]
    return f


SPARSE_CART_RANGE_M = wp.constant(0.25)
SPARSE_MIN_COSINE = wp.constant(0.995)


@wp.func
def sparse_reward(q: Any):
    """dm_control's sparse cart-pole reward (``Balance._get_reward(sparse=True)``): 1 while the cart is within 0.25 m
    of the centre and every pole's cosine in the world is at least 0.995 (within 5.7 degrees of upright), else 0. ``q``
    holds the cart's position, then each pole's angle relative to the one below."""
    inside = wp.abs(q[0]) <= SPARSE_CART_RANGE_M
    world = float(0.0)  # noqa: UP018 (a Warp variable the loop changes, not a constant)
    for k in range(1, len(q)):
        world += q[k]
        inside = inside and wp.cos(world) >= SPARSE_MIN_COSINE
    return wp.where(inside, 1.0, 0.0)


class CartTaskEnv(BatchedEnv):
    """A cart on a rail (joint role 'cart', prismatic) and the poles hinged above it (every further role, revolute),
    each role's joint named by the config field ``<role>_joint``; one action (the cart force)."""

    joint_roles = ("cart", "pole")
    num_actions = 1
    action_mirror = (-1.0,)

    def task_physical_params(self, values: dict) -> dict:
        """``force_per_action_n``: the cart force (N) of action 1."""
        return {"force_per_action_n": self.cfg.task.max_push_effort_n * values["actuator_scale"]}

    def joints(self, task: CartpoleConfig) -> list[JointRole]:
        import newton  # here, not at the top: the registry and the command line load this module without Newton

        kinds = [newton.JointType.PRISMATIC] + [newton.JointType.REVOLUTE] * (len(self.joint_roles) - 1)
        return [JointRole(role, getattr(task, f"{role}_joint"), kind, f"task.{role}_joint")
                for role, kind in zip(self.joint_roles, kinds, strict=True)]
