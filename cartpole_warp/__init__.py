"""cartpole_warp: batched cart-pole RL environments on NVIDIA Warp and Newton, trained with rsl-rl.

    import cartpole_warp
    env = cartpole_warp.make_env(num_envs=4096, device="cpu", seed=0)             # the default task, cartpole-balance
    env = cartpole_warp.tasks.make("cartpole-swingup", num_envs=4096, device="cpu", seed=0)
    obs, info = env.reset()
    obs, reward, terminated, truncated, info = env.step(actions)

Tasks live in ``tasks/`` (one module each, found by the registry ``cartpole_warp.tasks``); the rest is machinery that
knows no task: ``config.py`` (the config engine), ``scene.py`` (USD -> Newton), ``env.py`` (``BatchedEnv``),
``kernels.py`` (its Warp kernels), ``runtime.py`` (devices, shards, graphs), ``streams.py`` (torch and Warp on CUDA),
``wrappers/`` (rsl-rl, gymnasium, SB3), ``evaluation.py`` (policy rollouts and episode statistics), ``viz/``
(pictures), ``rl/`` (training with rsl-rl) and ``tools/`` (benchmarks).

Importing the package registers every task's gymnasium ids (``cartpole_warp/Cartpole-v0``,
``cartpole_warp/CartpoleSwingup-v0``, ... one or more per task: ``cartpole_warp.wrappers.gymnasium.env_ids()`` lists
them). DESIGN.md (in the repository) has the layers and the task seam.
"""

from . import tasks
from .config import ConfigError, EnvConfig, SimConfig, TaskConfig
from .deprecation import renamed
from .env import BatchedEnv
from .scene import StageError
from .wrappers.gymnasium import TaskGymEnv, TaskVectorEnv, register_envs


def make_env(num_envs: int | None = None, device: str | None = None, seed: int | None = None,
             preset: str | None = None, **overrides) -> BatchedEnv:
    """The default task's env (``tasks.DEFAULT_TASK``, cartpole-balance): ``tasks.make`` with that name."""
    return tasks.make(tasks.DEFAULT_TASK, num_envs=num_envs, device=device, seed=seed, preset=preset, **overrides)


register_envs()

__all__ = ["BatchedEnv", "TaskGymEnv", "TaskVectorEnv", "ConfigError", "EnvConfig", "SimConfig", "StageError",
           "TaskConfig", "make_env", "tasks"]

__getattr__ = renamed(__name__, {"CartpoleGymEnv": "TaskGymEnv", "CartpoleVectorEnv": "TaskVectorEnv"})
"""The old names (before they said what they serve), for one more release."""
