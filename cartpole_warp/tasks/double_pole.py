"""cart-double-pole-balance: two poles hinged in a chain on a cart, kept upright, in the spirit of Gymnasium's
``InvertedDoublePendulum`` (alive bonus minus tip-distance and velocity penalties), on Newton's own stage (the robot of
its ``robot_cartpole`` example, found in the installed ``newton`` package). The spec is ``CartDoublePoleEnv``'s
docstring."""

from __future__ import annotations

import importlib.util
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import warp as wp

from ..engine.kernels import END_NONE, FIRST_TASK_END, TaskFunctions
from ..settings.config import Finite, Name, NonNegative, Positive, require
from ..settings.presets import TrainSettings
from . import SolvedRule, Task, TaskSettings, register
from .cart_base import CartpoleConfig, CartTaskEnv, push_cart

CART_OUT = wp.constant(FIRST_TASK_END)
TIP_FELL = wp.constant(FIRST_TASK_END + 1)
NEWTON_STAGE = Path(importlib.util.find_spec("newton").origin).parent / "examples" / "assets" / "cartpole.usda"
"""Newton's cart + double pendulum: a 1 kg cart on an 8 m rail, two 1 m poles of 0.25 kg hinged in a chain."""


@dataclass
class DoublePoleConfig(CartpoleConfig):
    """A cart with two poles in a chain: joints, cart force, pole lengths, reward, termination and reset ranges."""

    cart_joint: Name = "railCartJoint"
    pole_joint: Name = "cartPoleJoint"
    pole2_joint: Name = "polePoleJoint"
    """The stage's revolute joint between pole 1 and pole 2 (joint role 'pole2')."""
    max_push_effort_n: NonNegative = 40.0
    pole1_length_m: Positive = 1.0
    """Distance from the first pole's hinge to the second's (m): the stage's, for the tip in the reward."""
    pole2_length_m: Positive = 1.0
    """Distance from the second pole's hinge to its tip (m): the stage's, for the tip in the reward."""
    reset_dist_m: Positive = 3.0
    """Terminate when |cart_pos| exceeds this (m)."""
    min_tip_height_m: Finite = 1.5
    """Terminate when the second pole's tip is less than this high above the cart's hinge (m)."""
    alive_reward: Finite = 1.0
    """Constant term of the reward."""
    tip_pos_weight: NonNegative = 0.001
    """Weight of the tip's squared distance (m^2) along the rail from the rail's centre."""
    tip_height_weight: NonNegative = 0.1
    """Weight of the tip's squared drop (m^2) below its upright height (pole1_length_m + pole2_length_m)."""
    pole1_vel_weight: NonNegative = 0.0001
    """Weight of pole1_vel^2 (per (rad/s)^2)."""
    pole2_vel_weight: NonNegative = 0.0005
    """Weight of pole2_vel^2 (per (rad/s)^2)."""
    reset_cart_pos_m: NonNegative = 0.5
    """Reset samples cart_pos ~ U(-this, this) (m)."""
    reset_pole_angle_rad: NonNegative = 0.1
    """Reset samples each pole's angle ~ U(-this, this) (rad)."""
    reset_vel: NonNegative = 0.1
    """Reset samples each joint's velocity ~ U(-this, this) (m/s or rad/s)."""

    def validate(self, env) -> None:
        require(self.reset_cart_pos_m < self.reset_dist_m,
                f"task.reset_cart_pos_m={self.reset_cart_pos_m:g} must be below task.reset_dist_m="
                f"{self.reset_dist_m:g} (else episodes end as they start)")
        require(self.min_tip_height_m < self.pole1_length_m + self.pole2_length_m,
                f"task.min_tip_height_m={self.min_tip_height_m:g} must be below the upright tip height "
                f"task.pole1_length_m + task.pole2_length_m={self.pole1_length_m + self.pole2_length_m:g}")
        spread = self.reset_pole_angle_rad  # lowest tip: both poles leaning the same way as far as the reset goes
        lowest = (self.pole1_length_m * math.cos(min(spread, math.pi))
                  + self.pole2_length_m * math.cos(min(2 * spread, math.pi)))
        require(lowest > self.min_tip_height_m,
                f"task.reset_pole_angle_rad={spread:g} can start an episode with the tip {lowest:.2f} m high, below "
                f"task.min_tip_height_m={self.min_tip_height_m:g} (else episodes end as they start)")



@wp.func
def tip(q: wp.vec3, p: Any):
    """The second pole's tip: (position along the rail (m), height above the cart's hinge (m)). A pole angle turns
    about +X with the rail along Y (Newton's stage): a positive angle leans the pole toward -Y."""
    absolute2 = q[1] + q[2]
    along = q[0] - p.pole1_length_m * wp.sin(q[1]) - p.pole2_length_m * wp.sin(absolute2)
    height = p.pole1_length_m * wp.cos(q[1]) + p.pole2_length_m * wp.cos(absolute2)
    return along, height


@wp.func
def observe(q: wp.vec3, qd: wp.vec3, p: Any):
    return wp.types.vector(q[0], q[1], q[2], qd[0], qd[1], qd[2], length=6, dtype=float)


@wp.func
def reward_and_end(q: wp.vec3, qd: wp.vec3, action: wp.types.vector(1, float), p: Any):
    along, height = tip(q, p)
    end = END_NONE
    if wp.abs(q[0]) > p.reset_dist_m:
        end = CART_OUT
    elif height < p.min_tip_height_m:
        end = TIP_FELL
    drop = p.pole1_length_m + p.pole2_length_m - height
    reward = (p.alive_reward - p.tip_pos_weight * along * along - p.tip_height_weight * drop * drop
              - p.pole1_vel_weight * qd[1] * qd[1] - p.pole2_vel_weight * qd[2] * qd[2])
    return reward, end


@wp.func
def sample_reset(rng_state: wp.array(dtype=wp.uint32), env: int, p: Any):
    s = rng_state[env]
    q = wp.vec3(wp.randf(s, -p.reset_cart_pos_m, p.reset_cart_pos_m),
                wp.randf(s, -p.reset_pole_angle_rad, p.reset_pole_angle_rad),
                wp.randf(s, -p.reset_pole_angle_rad, p.reset_pole_angle_rad))
    qd = wp.vec3(wp.randf(s, -p.reset_vel, p.reset_vel), wp.randf(s, -p.reset_vel, p.reset_vel),
                 wp.randf(s, -p.reset_vel, p.reset_vel))
    rng_state[env] = s
    return q, qd


class CartDoublePoleEnv(CartTaskEnv):
    """Batched cart + double pendulum balance, in the spirit of Gymnasium's ``InvertedDoublePendulum``.

    ==============  ==================================================================================
    observation     (N, 6) float32: [cart_pos (m), pole1_angle (rad), pole2_angle (rad), cart_vel (m/s),
                    pole1_vel (rad/s), pole2_vel (rad/s)]; pole1_angle from upright, pole2_angle relative to
                    pole 1 (as its joint measures it)
    action          (N, 1) or (N,) float32, clipped to [-1, 1]; cart force = 40 N * action
    reward          1 - 0.001 tip_pos^2 - 0.1 (2 m - tip_height)^2 - 1e-4 pole1_vel^2 - 5e-4 pole2_vel^2:
                    tip_pos (m) = cart_pos - sin(pole1_angle) - sin(pole1_angle + pole2_angle) is the tip of
                    pole 2 along the rail, tip_height (m) = cos(pole1_angle) + cos(pole1_angle + pole2_angle)
                    its height above the cart's hinge (1 m poles)
    terminated      |cart_pos| > 3 m ('cart_out_of_range') or tip_height < 1.5 m ('tip_fell'), on the state
                    after the physics step
    truncated       episode length reaches ``max_episode_length`` env steps (10 s)
    reset           cart_pos ~ U(-0.5, 0.5); pole1_angle, pole2_angle ~ U(-0.1, 0.1); each velocity
                    ~ U(-0.1, 0.1); one RNG state per env, seeded by ``seed``
    state           ``set_state``: (N, 6) [cart_pos, cart_vel, pole1_angle, pole1_vel, pole2_angle, pole2_vel]
    ==============  ==================================================================================

    Joint roles 'cart', 'pole' (pole 1, on the cart) and 'pole2': the cart-pole tasks' presets (e.g. ``robust``)
    randomize the cart and pole 1 of this one too.
    """

    config_class = DoublePoleConfig
    num_obs = 6
    obs_mirror = (-1.0,) * 6
    stage = NEWTON_STAGE
    joint_roles = ("cart", "pole", "pole2")
    task_ends = ("cart_out_of_range", "tip_fell")
    functions = TaskFunctions(observe=observe, reward_and_end=reward_and_end, sample_reset=sample_reset,
                              joint_forces=push_cart)


def settings(cfg: TrainSettings):
    """16 steps per env and 300 iterations; both networks normalise their observations."""
    cfg.agent.num_steps_per_env, cfg.agent.max_iterations = 16, 300
    cfg.agent.actor.obs_normalization = cfg.agent.critic.obs_normalization = True


TASK = register(Task(
    name="cart-double-pole-balance",
    env_class=CartDoublePoleEnv,
    summary="keep two poles in a chain upright on a cart (Newton's cart + double pendulum, 40 N cart, 10 s episodes)",
    solved=SolvedRule(min_time_limit_fraction=0.95),
    play_metric="time_limit_fraction",
    settings=TaskSettings(common=settings),
    gym_ids={"cartpole_warp/CartDoublePole-v0": None},
))
