"""cartpole-swingup: dm_control's ``cartpole.swingup`` (``dm_control/suite/cartpole.py``, smooth reward) on its model
(``usd/cartpole_dmc.usda``). The spec is ``CartpoleSwingupEnv``'s docstring."""

from __future__ import annotations

import math
from dataclasses import dataclass

import warp as wp

from ..config import Finite, NonNegative, Positive
from ..env import END_NONE, TaskFunctions, kernel_params
from . import SolvedRule, Task, register
from .cartpole import CartpoleConfig, CartTaskEnv, push_cart


@dataclass
class SwingupConfig(CartpoleConfig):
    """dm_control's swing-up: a pole that starts hanging down, a smooth reward for holding it up at the centre."""

    max_push_effort_n: NonNegative = 10.0
    """Cart force (N) for action 1 (dm_control's motor gear); actions are clipped to [-1, 1] first."""
    center_margin_m: Positive = 2.0
    """``centered`` = (1 + tolerance(cart_pos, margin)) / 2 (m)."""
    control_margin: Positive = 1.0
    """``small_control`` = (4 + quadratic tolerance(action, margin, value_at_margin=0)) / 5."""
    velocity_margin_rad_s: Positive = 5.0
    """``small_velocity`` = (1 + tolerance(pole_vel, margin)) / 2 (rad/s)."""
    reset_pole_angle_rad: Finite = math.pi
    """Resets start the pole at this angle (pi: hanging down) plus noise (rad)."""
    reset_noise: NonNegative = 0.01
    """Standard deviation of the Gaussian noise added to every joint position and velocity at reset (m, rad, m/s,
    rad/s)."""


Params = kernel_params(SwingupConfig)

GAUSSIAN_SCALE = wp.constant(math.sqrt(-2.0 * math.log(0.1)))
"""dm_control ``rewards.tolerance``'s gaussian sigmoid with its default value_at_margin 0.1."""


@wp.func
def tolerance(x: float, margin: float):
    """dm_control's ``rewards.tolerance(x, bounds=(0, 0), margin)`` with the gaussian sigmoid: 1 at 0, 0.1 at
    the margin."""
    d = x / margin * GAUSSIAN_SCALE
    return wp.exp(-0.5 * d * d)


@wp.func
def quadratic_tolerance(x: float, margin: float):
    """dm_control's ``rewards.tolerance(x, margin=margin, value_at_margin=0, sigmoid="quadratic")``."""
    d = x / margin
    return wp.max(1.0 - d * d, 0.0)


@wp.func
def observe(q: wp.vec2, qd: wp.vec2, p: Params):
    return wp.types.vector(q[0], wp.cos(q[1]), wp.sin(q[1]), qd[0], qd[1], length=5, dtype=float)


@wp.func
def evaluate(q: wp.vec2, qd: wp.vec2, action: wp.types.vector(1, float), p: Params):
    upright = (wp.cos(q[1]) + 1.0) / 2.0
    centered = (1.0 + tolerance(q[0], p.center_margin_m)) / 2.0
    small_control = (4.0 + quadratic_tolerance(action[0], p.control_margin)) / 5.0
    small_velocity = (1.0 + tolerance(qd[1], p.velocity_margin_rad_s)) / 2.0
    return upright * centered * small_control * small_velocity, END_NONE


@wp.func
def sample_reset(rng_state: wp.array(dtype=wp.uint32), env: int, p: Params):
    s = rng_state[env]
    cart_pos = p.reset_noise * wp.randn(s)
    pole_angle = p.reset_pole_angle_rad + p.reset_noise * wp.randn(s)
    cart_vel = p.reset_noise * wp.randn(s)
    pole_vel = p.reset_noise * wp.randn(s)
    rng_state[env] = s
    return wp.vec2(cart_pos, pole_angle), wp.vec2(cart_vel, pole_vel)


class CartpoleSwingupEnv(CartTaskEnv):
    """Batched cart-pole swing-up, dm_control's ``cartpole.swingup`` with its smooth reward.

    ==============  ==================================================================================
    observation     (N, 5) float32: [cart_pos (m), cos(pole_angle), sin(pole_angle), cart_vel (m/s),
                    pole_vel (rad/s)] (dm_control's order); pole_angle 0 is upright
    action          (N, 1) or (N,) float32, clipped to [-1, 1]; cart force = 10 N * action
    reward          upright * centered * small_control * small_velocity, in [0, 1]:
                    upright = (cos(pole_angle) + 1) / 2; centered = (1 + tol(cart_pos, 2 m)) / 2;
                    small_control = (4 + max(1 - action^2, 0)) / 5; small_velocity = (1 + tol(pole_vel, 5)) / 2,
                    tol(x, m) = exp(-0.5 (x / m)^2 * 2 ln 10) (dm_control's gaussian tolerance: 0.1 at the margin)
    terminated      never (the slider's +-1.8 m joint limits keep the cart on its rail); a non-finite physics state
                    ends the episode
    truncated       episode length reaches ``max_episode_length`` env steps (10 s)
    reset           pole_angle = pi + 0.01 N(0, 1) (hanging down), cart_pos, cart_vel, pole_vel = 0.01 N(0, 1)
    state           ``set_state``: (N, 4) [cart_pos, cart_vel, pole_angle, pole_vel]
    ==============  ==================================================================================
    """

    config_class = SwingupConfig
    params_type = Params
    num_obs = 5
    obs_mirror = (-1.0, 1.0, -1.0, -1.0, -1.0)
    stage = "cartpole_dmc.usda"
    functions = TaskFunctions(observe=observe, evaluate=evaluate, sample_reset=sample_reset,
                              joint_forces=push_cart)


TASK = register(Task(
    name="cartpole-swingup",
    env_class=CartpoleSwingupEnv,
    summary="swing the pole up from hanging down and hold it (dm_control's swing-up, 10 N cart, 10 s episodes)",
    solved=SolvedRule(min_reward_per_step=0.8, full_episodes_only=True),
    play_metric="full_reward_per_step",
    defaults={"env": {"sim": {"physics_dt": 0.01, "decimation": 2}},
              # symmetry off: no faster on an H100, and seed 1 never solved with it on a 2-core CPU; 2 epochs: ~25%
              # fewer iterations (docs/benchmarks.md)
              "agent": {"max_iterations": 500, "num_steps_per_env": 16,
                        "algorithm": {"entropy_coef": 0.02, "symmetry": False, "num_learning_epochs": 2},
                        "actor": {"obs_normalization": True}, "critic": {"obs_normalization": True}}},
    gym_ids={"cartpole_warp/CartpoleSwingup-v0": None},
))
