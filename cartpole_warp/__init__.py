"""cartpole_warp: a batched cartpole RL environment on NVIDIA Warp and Newton.

    import cartpole_warp
    env = cartpole_warp.make_env(num_envs=4096, device="cpu", seed=0, preset="default")
    obs, info = env.reset()
    obs, reward, terminated, truncated, info = env.step(actions)
"""

from .config import ConfigError, EnvConfig, SimConfig, TaskConfig, env_config
from .env import CartpoleEnv, make_env
from .scene import StageError

__all__ = ["CartpoleEnv", "ConfigError", "EnvConfig", "SimConfig", "StageError", "TaskConfig", "env_config", "make_env"]
