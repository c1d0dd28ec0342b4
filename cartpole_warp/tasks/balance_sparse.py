"""cartpole-balance-sparse: the balance (``balance.py``, its stage, ends and resets) with dm_control's sparse reward
(its ``balance_sparse``): 1 while the cart is within 0.25 m of the centre and the pole within 5.7 degrees of upright."""

import dataclasses
from typing import Any

import warp as wp

from . import SolvedRule, TaskSettings, balance, dense_path, register
from .cart_base import sparse_reward


@wp.func
def reward_and_end(q: wp.vec2, qd: wp.vec2, action: wp.types.vector(1, float), p: Any):
    unused, end = balance.reward_and_end(q, qd, action, p)
    return sparse_reward(q), end


class CartpoleBalanceSparseEnv(balance.CartpoleBalanceEnv):
    """``CartpoleBalanceEnv`` with reward ``cart_base.sparse_reward``: 1 in the band, 0 elsewhere and at the end."""

    functions = dataclasses.replace(balance.CartpoleBalanceEnv.functions, reward_and_end=reward_and_end)


register(dataclasses.replace(
    balance.TASK, name="cartpole-balance-sparse", env_class=CartpoleBalanceSparseEnv,
    play_metric="mean_reward_per_step",
    summary="keep the pole up, rewarded only in dm_control's sparse band (cart within 0.25 m, pole within 5.7 deg)",
    solved=SolvedRule(min_reward_per_step=0.8, min_time_limit_fraction=0.95),
    gym_ids={"cartpole_warp/CartpoleBalanceSparse-v0": None},
    settings=TaskSettings(common=dense_path)))  # the balance's CPU networks were not measured on the sparse reward
