"""cartpole_warp: a batched cartpole RL environment on NVIDIA Warp and Newton.

    import cartpole_warp
    env = cartpole_warp.make_env(num_envs=4096, device="cpu", seed=0, preset="default")
    obs, info = env.reset()
    obs, reward, terminated, truncated, info = env.step(actions)

The task is ``config.py`` (settings), ``scene.py`` (the USD stage in Newton), ``kernels.py`` (observations, reward,
resets in Warp) and ``env.py`` (``CartpoleEnv``); ``runtime.py`` is robot-agnostic machinery; ``wrappers/`` presents
the env to rsl-rl, gymnasium and Stable-Baselines3; ``rl/`` trains with rsl-rl; ``viz/`` draws pictures.

Importing the package registers the gymnasium ids ``cartpole_warp/Cartpole-v0`` (preset 'default') and
``cartpole_warp/CartpoleTutorial-v0`` (preset 'tutorial'); see ``cartpole_warp.wrappers.gymnasium``.
"""

from .config import ConfigError, EnvConfig, SimConfig, TaskConfig, env_config
from .env import CartpoleEnv, make_env
from .scene import StageError
from .wrappers.gymnasium import CartpoleGymEnv, CartpoleVectorEnv, register_envs

register_envs()

__all__ = ["CartpoleEnv", "CartpoleGymEnv", "CartpoleVectorEnv", "ConfigError", "EnvConfig", "SimConfig", "StageError",
           "TaskConfig", "env_config", "make_env"]
