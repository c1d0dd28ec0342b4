"""cart-two-pole-swingup and cart-three-pole-swingup: dm_control's ``cartpole.two_poles`` and ``three_poles``, the
swing-up (``swingup.py``: its reward, resets and settings) on a chain of 2 or 3 identical poles
(``usd/cartpole_dmc_<n>poles.usda``, dm_control's ``_make_model(n)``). The spec is ``CartTwoPoleSwingupEnv``'s
docstring."""

from dataclasses import dataclass, replace

from ..settings.config import Name
from ..settings.presets import TrainSettings
from . import Configure, SolvedRule, TaskSettings, compose, dense_path, register, swingup


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


def chain_settings(width: int, steps_per_env: int) -> Configure:
    """A chain's settings over the single pole's: thousands of iterations, an evaluation at most every 100 (so that
    evaluations stay a small part of training), ``width`` x ``width`` networks (the single pole's 32 x 32 levelled
    off on the chains), ``steps_per_env`` steps per env, and the dense path (``tasks.dense_path``: on the tile path,
    a 2.7x faster three-pole step, the two poles' seed 0 did not solve)."""
    def settings(cfg: TrainSettings):
        dense_path(cfg)
        cfg.agent.max_iterations, cfg.agent.num_steps_per_env, cfg.eval.max_interval = 15000, steps_per_env, 100
        cfg.agent.actor.hidden_dims, cfg.agent.critic.hidden_dims = [width, width], [width, width]

    return compose(swingup.settings, settings)


def evaluate_in_step(cfg: TrainSettings):
    """On a GPU the three poles evaluate inside the training's step, where their many evaluations cost more than the
    extra envs and the verdict's wait (docs/benchmarks.md)."""
    cfg.eval.in_step = True


for env_class, words, min_reward_per_step, width, steps_per_env, on_gpu, gym_id in (
        (CartTwoPoleSwingupEnv, "two", 0.7, 128, 32, None, "CartTwoPoleSwingup"),  # 32 steps: every seed solved
        (CartThreePoleSwingupEnv, "three", 0.5, 256, 16, evaluate_in_step, "CartThreePoleSwingup")):
    register(replace(
        swingup.TASK, name=f"cart-{words}-pole-swingup", env_class=env_class,
        summary=f"swing a chain of {words} poles up and hold it (dm_control's {words}_poles, 10 N cart, 10 s episodes)",
        solved=SolvedRule(min_reward_per_step=min_reward_per_step, full_episodes_only=True),
        # the single pole's device and learner settings were not measured on the chains
        settings=TaskSettings(common=chain_settings(width, steps_per_env), on_gpu=on_gpu),
        gym_ids={f"cartpole_warp/{gym_id}-v0": None}))
