"""cart-two-pole-swingup and cart-three-pole-swingup: dm_control's ``cartpole.two_poles`` and ``three_poles``, the
swing-up (``swingup.py``: its reward, resets and settings) on a chain of 2 or 3 identical poles
(``usd/cartpole_dmc_<n>poles.usda``, dm_control's ``_make_model(n)``). The spec is ``CartTwoPoleSwingupEnv``'s
docstring."""

from dataclasses import dataclass, replace

from ..settings.config import Name, merge
from . import DENSE_PATH, SolvedRule, register, swingup


@dataclass
class TwoPoleConfig(swingup.SwingupConfig):
    """The swing-up's settings and the joint of the second pole."""

    pole2_joint: Name = "pole2Joint"
    """The stage's revolute joint between pole 1 and pole 2 (joint role 'pole2')."""


@dataclass
class ThreePoleConfig(TwoPoleConfig):
    """The swing-up's settings and the joints of the second and third poles."""

    pole3_joint: Name = "pole3Joint"
    """The stage's revolute joint between pole 2 and pole 3 (joint role 'pole3')."""


class CartTwoPoleSwingupEnv(swingup.CartpoleSwingupEnv):
    """dm_control's ``two_poles``: ``CartpoleSwingupEnv`` with a second 1 m, 0.1 kg pole hinged on top of the first.

    ==============  ==================================================================================
    observation     (N, 8) float32: [cart_pos (m), cos(phi1), sin(phi1), cos(phi2), sin(phi2), cart_vel (m/s),
                    pole_vel, pole2_vel (rad/s)]; phi_k is pole k's angle in the world (0 upright), the sum of
                    the joint angles up to it; the velocities are the joints' (pole 2's relative to pole 1)
    action          as the swing-up's: cart force = 10 N * action
    reward          upright * centered * small_control * small_velocity as the swing-up's, with upright the mean
                    of (cos(phi_k) + 1) / 2 over the poles and small_velocity = (1 + min_k tol(pole_k_vel, 5)) / 2
    terminated      never; truncated at the time limit (10 s)
    reset           pole 1 at pi + 0.01 N(0, 1) (hanging down), each further pole at 0.1 N(0, 1) from the one below,
                    cart_pos and every velocity 0.01 N(0, 1)
    state           ``set_state``: (N, 6) [cart_pos, cart_vel, pole_angle, pole_vel, pole2_angle, pole2_vel]
    ==============  ==================================================================================
    """

    config_class = TwoPoleConfig
    joint_roles = ("cart", "pole", "pole2")
    num_obs = 8
    obs_mirror = swingup.swingup_obs_mirror(2)
    stage = "cartpole_dmc_2poles.usda"
    functions = swingup.swingup_functions(2)


class CartThreePoleSwingupEnv(CartTwoPoleSwingupEnv):
    """dm_control's ``three_poles``: ``CartTwoPoleSwingupEnv`` with a third pole on top (observation (N, 11): cart_pos,
    cos and sin of each pole's world angle, cart_vel and the three pole joints' velocities; state (N, 8))."""

    config_class = ThreePoleConfig
    joint_roles = ("cart", "pole", "pole2", "pole3")
    num_obs = 11
    obs_mirror = swingup.swingup_obs_mirror(3)
    stage = "cartpole_dmc_3poles.usda"
    functions = swingup.swingup_functions(3)


for env_class, words, min_reward_per_step, width, steps_per_env, gpu_defaults, gym_id in (
        (CartTwoPoleSwingupEnv, "two", 0.7, 128, 32, {}, "CartTwoPoleSwingup"),
        (CartThreePoleSwingupEnv, "three", 0.5, 256, 16, {"eval": {"in_step": True}}, "CartThreePoleSwingup")):
    # thousands of iterations: an evaluation at most every 100, so that evaluations stay a small part of training;
    # wider networks than the single pole's 32 x 32, with which the chains levelled off, and for two poles 32 steps
    # per env, with which every seed solved; on a GPU the three poles evaluate inside the training's step, where
    # their many evaluations cost more than the extra envs and the verdict's wait (docs/benchmarks.md); the dense path
    # (DENSE_PATH): on the tile path, a 2.7x faster three-pole step, the two poles' seed 0 did not solve
    networks = {"hidden_dims": [width, width]}
    register(replace(
        swingup.TASK, name=f"cart-{words}-pole-swingup", env_class=env_class,
        summary=f"swing a chain of {words} poles up and hold it (dm_control's {words}_poles, 10 N cart, 10 s episodes)",
        solved=SolvedRule(min_reward_per_step=min_reward_per_step, full_episodes_only=True),
        defaults=merge(swingup.TASK.defaults, {**DENSE_PATH,
                                               "agent": {"max_iterations": 15000, "num_steps_per_env": steps_per_env,
                                                         "actor": networks, "critic": networks},
                                               "eval": {"max_interval": 100}}),
        gpu_defaults=gpu_defaults, cpu_defaults={},  # the single pole's were not measured on the chains
        learner_defaults={},  # the swing-up's were not measured here
        gym_ids={f"cartpole_warp/{gym_id}-v0": None}))
