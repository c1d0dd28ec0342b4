"""What the cart-pole tasks share (no task itself): the settings that name the two joints and scale the cart force,
and an env base whose joint roles are the cart (prismatic) and the pole (revolute)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import newton
import warp as wp

from ..config import Name, NonNegative, TaskConfig
from ..env import BatchedEnv
from ..scene import JointRole


@dataclass
class CartpoleConfig(TaskConfig):
    """Settings of every cart-pole task."""

    cart_joint: Name = "cartJoint"
    """The stage's prismatic joint that moves the cart: its name, or its full prim path where the name repeats."""
    pole_joint: Name = "poleJoint"
    """The stage's revolute joint of the pole: its name, or its full prim path where the name repeats."""
    max_push_effort_n: NonNegative = 400.0
    """Cart force (N) for action 1; actions are clipped to [-1, 1] first."""


@wp.func
def push_cart(action: wp.types.vector(1, float), p: Any):
    """``TaskFunctions.joint_forces`` of a cart-pole task: max_push_effort_n * action on the cart, nothing on the pole
    (generic over the task's params struct)."""
    return wp.vec2(p.max_push_effort_n * action[0], 0.0)


class CartpoleTaskEnv(BatchedEnv):
    """A cart on a rail and a pole hinged to it: joint roles ('cart', 'pole'), one action (the cart force)."""

    joint_roles = ("cart", "pole")
    num_actions = 1

    def task_physical_params(self, values: dict) -> dict:
        """``force_per_action_n``: the cart force (N) of action 1."""
        return {"force_per_action_n": self.cfg.task.max_push_effort_n * values["actuator_scale"]}

    def joints(self, task: CartpoleConfig) -> list[JointRole]:
        return [JointRole("cart", task.cart_joint, newton.JointType.PRISMATIC, "task.cart_joint"),
                JointRole("pole", task.pole_joint, newton.JointType.REVOLUTE, "task.pole_joint")]
