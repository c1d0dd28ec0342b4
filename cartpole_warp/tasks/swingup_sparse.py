"""cartpole-swingup-sparse: dm_control's ``cartpole.swingup_sparse``, the swing-up (``swingup.py``) rewarded 1 only
while the cart is within 0.25 m of the centre and the pole within 5.7 degrees of upright, else 0."""

import dataclasses
from typing import Any

import warp as wp

from ..engine.kernels import END_NONE
from ..settings.presets import TrainSettings
from . import SolvedRule, TaskSettings, compose, dense_path, register, swingup
from .cart_base import sparse_reward


@wp.func
def reward_and_end(q: wp.vec2, qd: wp.vec2, action: wp.types.vector(1, float), p: Any):
    return sparse_reward(q), END_NONE


class CartpoleSwingupSparseEnv(swingup.CartpoleSwingupEnv):
    """``CartpoleSwingupEnv`` with reward ``cart_base.sparse_reward``: 1 in the band, else 0."""

    functions = dataclasses.replace(swingup.CartpoleSwingupEnv.functions, reward_and_end=reward_and_end)


def settings(cfg: TrainSettings):
    """2000 iterations, 1.5x the slowest seed measured (docs/benchmarks.md): the reward says nothing until the pole is
    in the band."""
    cfg.agent.max_iterations = 2000


register(dataclasses.replace(
    swingup.TASK, name="cartpole-swingup-sparse", env_class=CartpoleSwingupSparseEnv,
    summary="swing the pole up, rewarded only in dm_control's sparse band (its swingup_sparse)",
    solved=SolvedRule(min_reward_per_step=0.5, full_episodes_only=True),
    # measured without the smooth swing-up's device and learner settings
    settings=TaskSettings(common=compose(swingup.settings, dense_path, settings)),
    gym_ids={"cartpole_warp/CartpoleSwingupSparse-v0": None}))
