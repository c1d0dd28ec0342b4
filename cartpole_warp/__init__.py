"""cartpole_warp: a batched cartpole RL environment on NVIDIA Warp and Newton.

    import cartpole_warp
    env = cartpole_warp.make_env(num_envs=4096, device="cpu", seed=0, preset="default")
    obs, info = env.reset()
    obs, reward, terminated, truncated, info = env.step(actions)

Importing the package registers the gymnasium ids ``cartpole_warp/Cartpole-v0`` (preset 'default') and
``cartpole_warp/CartpoleTutorial-v0`` (preset 'tutorial'); see ``cartpole_warp.gym_env``.
"""

from .config import ConfigError, EnvConfig, SimConfig, TaskConfig, env_config
from .env import CartpoleEnv, make_env
from .gym_env import CartpoleGymEnv, CartpoleVectorEnv, register_envs
from .scene import StageError

register_envs()

__all__ = ["CartpoleEnv", "CartpoleGymEnv", "CartpoleVectorEnv", "ConfigError", "EnvConfig", "SimConfig", "StageError",
           "TaskConfig", "env_config", "make_env"]
