"""Stable-Baselines3 adapter: ``TaskSb3VecEnv``, a task's ``BatchedEnv`` as an SB3 ``VecEnv``.

    from stable_baselines3 import PPO
    from cartpole_warp import make_env
    from cartpole_warp.wrappers.sb3 import TaskSb3VecEnv

    venv = TaskSb3VecEnv(make_env(num_envs=64, preset="default"))
    PPO("MlpPolicy", venv).learn(100_000)

Needs the ``[sb3]`` extra (stable-baselines3).
"""

from __future__ import annotations

import time
from typing import Any

import numpy as np

try:
    from stable_baselines3.common.vec_env import VecEnv
except ModuleNotFoundError as err:
    raise ModuleNotFoundError(f"cartpole_warp.wrappers.sb3 needs the sb3 extra ({err.name} is missing): "
                              "pip install 'cartpole_warp[sb3]'", name=err.name) from None

from ..engine.env import BatchedEnv
from ..settings.deprecation import renamed
from .gymnasium import actions_tensor, env_frames, render_metadata


class TaskSb3VecEnv(VecEnv):
    """SB3 ``VecEnv`` over one ``BatchedEnv`` of any task (one copy of the data per step, no loop over envs).

    ``step_wait`` returns numpy (obs (N, num_obs) float32 or camera frames (``observation_space``), rewards (N,)
    float32, dones (N,) bool, infos). Envs that end are already reset (SB3's convention); their info holds
    ``terminal_observation``, ``TimeLimit.truncated`` and ``episode`` {``r``, ``l``, ``t``} as SB3's ``Monitor``
    writes it, so no Monitor wrapper is needed.
    ``seed(s)`` takes effect at the next ``reset`` (SB3's convention) and re-seeds the env's RNG with ``s``.

    The N sub-envs share one ``BatchedEnv``: ``get_attr``, ``set_attr`` and ``env_method`` act on it once
    and report its value for each requested index. ``episode_count`` counts the episodes ended so far.
    """

    def __init__(self, env: BatchedEnv, render_mode: str | None = None):
        self.env = env
        self.render_mode = render_mode
        super().__init__(env.num_envs, env.single_observation_space, env.single_action_space)
        self.metadata = {**self.metadata, **render_metadata(env)}
        self._frames = env_frames(env, render_mode)
        self.episode_count = 0
        self._start_time = time.time()
        self._actions = None

    def reset(self):
        obs, _ = self.env.reset(seed=self._seeds[0])
        self._reset_seeds()
        self._reset_options()
        return obs.cpu().numpy()

    def step_async(self, actions: np.ndarray) -> None:
        self._actions = actions_tensor(actions, self.num_envs, self.env)

    def step_wait(self):
        if self._actions is None:
            raise RuntimeError("step_wait() called without a pending step_async()")
        obs, reward, terminated, truncated, info = self.env.step(self._actions)
        self._actions = None
        terminated, truncated = terminated.cpu().numpy(), truncated.cpu().numpy()
        dones = terminated | truncated
        infos: list[dict[str, Any]] = [{} for _ in range(self.num_envs)]
        ended = np.flatnonzero(dones)
        if ended.size:
            self.episode_count += ended.size
            elapsed = round(time.time() - self._start_time, 6)
            final_obs = info["final_obs"].cpu().numpy()
            returns = info["episode_return"].cpu().numpy()
            lengths = info["episode_length"].cpu().numpy()
            for i in ended.tolist():
                infos[i] = {
                    "terminal_observation": final_obs[i],
                    "TimeLimit.truncated": bool(truncated[i] and not terminated[i]),
                    "episode": {"r": float(returns[i]), "l": int(lengths[i]), "t": elapsed},
                }
        return obs.cpu().numpy(), reward.cpu().numpy(), dones, infos

    def get_images(self):
        """``num_envs`` frames (H, W, 3) uint8, env ``i`` drawn when read (needs render_mode='rgb_array')."""
        if self._frames is None:
            raise ValueError("get_images() needs TaskSb3VecEnv(env, render_mode='rgb_array')")
        return self._frames

    def render(self, mode: str | None = None):
        """With render_mode 'rgb_array': the first env now, (H, W, 3) uint8 (what VecVideoRecorder records);
        ``get_images()`` draws any env."""
        if self._frames is None or mode not in (None, "rgb_array"):
            return super().render(mode)
        return self._frames[0]

    def close(self) -> None:
        self._actions = None
        self.env.close()

    def _count(self, indices) -> int:
        return len(list(self._get_indices(indices)))

    def get_attr(self, attr_name: str, indices=None) -> list[Any]:
        value = self.render_mode if attr_name == "render_mode" else getattr(self.env, attr_name)
        return [value] * self._count(indices)

    def set_attr(self, attr_name: str, value: Any, indices=None) -> None:
        setattr(self.env, attr_name, value)

    def env_method(self, method_name: str, *method_args, indices=None, **method_kwargs) -> list[Any]:
        result = getattr(self.env, method_name)(*method_args, **method_kwargs)
        return [result] * self._count(indices)

    def env_is_wrapped(self, wrapper_class, indices=None) -> list[bool]:
        return [False] * self._count(indices)

__getattr__ = renamed(__name__, {"CartpoleSb3VecEnv": "TaskSb3VecEnv"})
"""The old names (before they said what they serve), until ``settings.deprecation.REMOVED_IN``."""
