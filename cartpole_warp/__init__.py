"""cartpole_warp: batched cart-pole RL environments on NVIDIA Warp and Newton, trained with rsl-rl.

    import cartpole_warp
    env = cartpole_warp.make_env(num_envs=4096, device="cpu", seed=0)             # the default task, cartpole-balance
    env = cartpole_warp.tasks.make("cartpole-swingup", num_envs=4096, device="cpu", seed=0)
    obs, info = env.reset()
    obs, reward, terminated, truncated, info = env.step(actions)

Tasks live in ``tasks/`` (one module each, found by the registry ``cartpole_warp.tasks``); the rest is machinery that
knows no task, a folder per layer: ``settings/`` (the config schemas, presets and files), ``engine/`` (the stage, the
batched env, its kernels, camera and randomization), ``evaluation/`` (episode statistics, policy rollouts,
robustness), ``viz/`` (pictures), ``wrappers/`` (rsl-rl, gymnasium, SB3), ``rl/`` (training with rsl-rl, a folder
per learner), ``identification/`` (physics fitted to recordings) and ``tools/`` (benchmarks); the programs
(``train``, ``play``, ``warmup``, ``cli``) sit here.

Importing the package registers every task's gymnasium ids (``cartpole_warp/Cartpole-v0``,
``cartpole_warp/CartpoleSwingup-v0``, ... one or more per task: ``cartpole_warp.wrappers.gymnasium.env_ids()`` lists
them). DESIGN.md (in the repository) has the layers and the task seam.
"""

from . import tasks
from .engine.env import BatchedEnv
from .engine.scene import StageError
from .settings.config import ConfigError, EnvConfig, SimConfig, TaskConfig
from .settings.deprecation import alias_moved_modules, renamed
from .wrappers.gymnasium import TaskGymEnv, TaskVectorEnv, register_envs


def make_env(num_envs: int | None = None, device: str | None = None, seed: int | None = None,
             preset: str | None = None, **overrides) -> BatchedEnv:
    """The default task's env (``tasks.DEFAULT_TASK``, cartpole-balance): ``tasks.make`` with that name."""
    return tasks.make(tasks.DEFAULT_TASK, num_envs=num_envs, device=device, seed=seed, preset=preset, **overrides)


register_envs()

__all__ = ["BatchedEnv", "TaskGymEnv", "TaskVectorEnv", "ConfigError", "EnvConfig", "SimConfig", "StageError",
           "TaskConfig", "make_env", "tasks"]

__getattr__ = renamed(__name__, {"CartpoleGymEnv": "TaskGymEnv", "CartpoleVectorEnv": "TaskVectorEnv"})
"""The old names (before they said what they serve), until ``settings.deprecation.REMOVED_IN``."""

MOVED_MODULES = {
    **{f"{__name__}.{name}": f"{__name__}.engine.{name}"
       for name in ("env", "kernels", "camera", "randomization", "scene", "runtime", "streams")},
    **{f"{__name__}.{name}": f"{__name__}.settings.{name}" for name in ("config", "agent", "presets", "files")},
    f"{__name__}.deprecation": f"{__name__}.settings.deprecation",
    f"{__name__}.statistics": f"{__name__}.evaluation.statistics",
    f"{__name__}.robustness": f"{__name__}.evaluation.robustness",
    f"{__name__}.tasks.cartpole": f"{__name__}.tasks.cart_base",
    f"{__name__}.rl.learner": f"{__name__}.rl.learners",
    **{f"{__name__}.rl.{old}": f"{__name__}.rl.learners.{new}" for old, new in (
        ("ppo_learner", "ppo.learner"), ("ppo", "ppo.sync_free"), ("population_ppo", "batched_ppo.update"),
        ("sapg", "sapg.learner"), ("apg", "shac.learner"))},
}
"""The modules' old paths (before the layers became folders, the cart tasks' shared module, which is no task, and
the learners before their wing) -> their new ones, until ``settings.deprecation.REMOVED_IN``; the old
``cartpole_warp.evaluation`` module's names are answered by the ``evaluation`` package."""
alias_moved_modules(MOVED_MODULES)
