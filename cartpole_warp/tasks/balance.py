"""cartpole-balance: the Isaac Sim tutorial "Custom RL Example using Stable Baselines" (with a time limit by default;
its ``tutorial`` preset is the tutorial exactly). The spec is ``CartpoleBalanceEnv``'s docstring."""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import warp as wp

from ..engine.kernels import END_NONE, FIRST_TASK_END, TaskFunctions
from ..settings.config import Finite, NonNegative, Positive, require
from ..settings.presets import TrainSettings
from . import SolvedRule, Task, TaskSettings, register
from .cart_base import CartpoleConfig, CartTaskEnv, push_cart

CART_OUT = wp.constant(FIRST_TASK_END)
POLE_FELL = wp.constant(FIRST_TASK_END + 1)


@dataclass
class BalanceConfig(CartpoleConfig):
    """The tutorial's cartpole task: action scale, reward, termination, reset ranges, time limit."""

    reset_dist_m: Positive = 3.0
    """Terminate when |cart_pos| exceeds this (m)."""
    max_pole_angle_rad: Positive = math.pi / 2
    """Terminate when |pole_angle| exceeds this (rad)."""
    failure_reward: Finite = -2.0
    """Reward that replaces the shaped reward on the step that terminates."""
    alive_reward: Finite = 1.0
    """Constant term of the shaped reward."""
    pole_angle_weight: NonNegative = 1.0
    """Weight of pole_angle^2 (per rad^2) subtracted from the reward."""
    cart_vel_weight: NonNegative = 0.01
    """Weight of |cart_vel| (per m/s) subtracted from the reward."""
    pole_vel_weight: NonNegative = 0.005
    """Weight of |pole_vel| (per rad/s) subtracted from the reward."""
    reset_cart_pos_m: NonNegative = 1.0
    """Reset samples cart_pos ~ U(-this, this) (m)."""
    reset_cart_vel_m_s: NonNegative = 0.5
    """Reset samples cart_vel ~ U(-this, this) (m/s)."""
    reset_pole_angle_rad: NonNegative = 0.125 * math.pi
    """Reset samples pole_angle ~ U(-this, this) (rad)."""
    reset_pole_vel_rad_s: NonNegative = 0.25 * math.pi
    """Reset samples pole_vel ~ U(-this, this) (rad/s)."""

    def validate(self, env) -> None:
        require(self.reset_cart_pos_m < self.reset_dist_m,
                f"task.reset_cart_pos_m={self.reset_cart_pos_m:g} must be below task.reset_dist_m="
                f"{self.reset_dist_m:g} (else episodes end as they start)")
        require(self.reset_pole_angle_rad < self.max_pole_angle_rad,
                f"task.reset_pole_angle_rad={self.reset_pole_angle_rad:g} must be below task.max_pole_angle_rad="
                f"{self.max_pole_angle_rad:g} (else episodes end as they start)")



@wp.func
def observe(q: wp.vec2, qd: wp.vec2, p: Any):
    return wp.vec4(q[0], qd[0], q[1], qd[1])


@wp.func
def reward_and_end(q: wp.vec2, qd: wp.vec2, action: wp.types.vector(1, float), p: Any):
    end = END_NONE
    if wp.abs(q[0]) > p.reset_dist_m:
        end = CART_OUT
    elif wp.abs(q[1]) > p.max_pole_angle_rad:
        end = POLE_FELL
    reward = p.failure_reward
    if end == END_NONE:
        reward = (p.alive_reward - p.pole_angle_weight * q[1] * q[1] - p.cart_vel_weight * wp.abs(qd[0])
                  - p.pole_vel_weight * wp.abs(qd[1]))
    return reward, end


@wp.func
def sample_reset(rng_state: wp.array(dtype=wp.uint32), env: int, p: Any):
    s = rng_state[env]
    cart_pos = wp.randf(s, -p.reset_cart_pos_m, p.reset_cart_pos_m)
    cart_vel = wp.randf(s, -p.reset_cart_vel_m_s, p.reset_cart_vel_m_s)
    pole_angle = wp.randf(s, -p.reset_pole_angle_rad, p.reset_pole_angle_rad)
    pole_vel = wp.randf(s, -p.reset_pole_vel_rad_s, p.reset_pole_vel_rad_s)
    rng_state[env] = s
    return wp.vec2(cart_pos, pole_angle), wp.vec2(cart_vel, pole_vel)


class CartpoleBalanceEnv(CartTaskEnv):
    """Batched cartpole, the Isaac Sim "Custom RL Example using Stable Baselines" task.

    ==============  ==================================================================================
    observation     (N, 4) float32: [cart_pos (m), cart_vel (m/s), pole_angle (rad), pole_vel (rad/s)]
    action          (N, 1) or (N,) float32, clipped to [-1, 1]; cart force = max_push_effort_n * action
    reward          1 - pole_angle^2 - 0.01 |cart_vel| - 0.005 |pole_vel|; -2 on the terminating step
    terminated      |cart_pos| > 3 m (end reason 'cart_out_of_range') or |pole_angle| > pi/2 ('pole_fell'),
                    on the state after the physics step
    truncated       episode length reaches ``max_episode_length`` env steps (not terminated)
    reset           cart_pos ~ U(-1, 1), cart_vel ~ U(-0.5, 0.5), pole_angle ~ U(-pi/8, pi/8),
                    pole_vel ~ U(-pi/4, pi/4); one RNG state per env, seeded by ``seed``
    state           ``set_state``: (N, 4) [cart_pos, cart_vel, pole_angle, pole_vel]
    ==============  ==================================================================================
    """

    config_class = BalanceConfig
    num_obs = 4
    obs_mirror = (-1.0,) * 4
    stage = "cartpole.usda"
    task_ends = ("cart_out_of_range", "pole_fell")
    functions = TaskFunctions(observe=observe, reward_and_end=reward_and_end, sample_reset=sample_reset,
                              joint_forces=push_cart)


def cpu_settings(cfg: TrainSettings):
    """On a CPU, 8 x 8 networks: there their products and ELUs cost as much as the env, and 8 x 8 solved seeds 0-9 as
    32 x 32 did, sooner (docs/benchmarks.md)."""
    cfg.agent.actor.hidden_dims, cfg.agent.critic.hidden_dims = [8, 8], [8, 8]


TASK = register(Task(
    name="cartpole-balance",
    env_class=CartpoleBalanceEnv,
    summary="keep the pole up (the Isaac Sim tutorial's task, 400 N cart, 10 s episodes)",
    solved=SolvedRule(min_reward_per_step=0.9, min_time_limit_fraction=0.95),
    play_metric="time_limit_fraction",
    gym_ids={"cartpole_warp/Cartpole-v0": None, "cartpole_warp/CartpoleTutorial-v0": "tutorial"},
    settings=TaskSettings(on_cpu=cpu_settings),
))
