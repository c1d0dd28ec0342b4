"""gymnasium adapters of any registered task: ``TaskGymEnv`` (one env, ``gymnasium.Env``) and
``TaskVectorEnv`` (batched).

    import gymnasium as gym
    import cartpole_warp  # registers every task's ids (its Task.gym_ids)

    env = gym.make("cartpole_warp/CartpoleTutorial-v0")  # the Isaac Sim tutorial, one env
    envs = gym.make_vec("cartpole_warp/CartpoleSwingup-v0", num_envs=4096, vectorization_mode="vector_entry_point")

Both are thin translations of a ``BatchedEnv`` (torch in, numpy out); the task logic lives in the env, and the
spaces come from its sizes.
"""

from __future__ import annotations

import dataclasses
import os
from typing import TYPE_CHECKING, Any

import gymnasium as gym
import numpy as np
from gymnasium.vector import AutoresetMode, VectorEnv

from .. import tasks
from ..engine.env import BatchedEnv
from ..settings.config import EnvConfig
from ..settings.deprecation import renamed, renamed_attribute

if TYPE_CHECKING:
    import torch  # imported where used: parsing a command line needs no torch


def actions_tensor(actions, num_envs: int, env: BatchedEnv) -> torch.Tensor:
    """(num_envs, num_actions) float32 tensor on the env's device from an array-like of that many values."""
    import torch

    array, shape = np.asarray(actions, dtype=np.float32), (num_envs, env.num_actions)
    if array.size != num_envs * env.num_actions:
        raise ValueError(f"expected {array.size and num_envs * env.num_actions} action value(s) (shape {shape}), "
                         f"got shape {array.shape}")
    return torch.from_numpy(array.reshape(shape)).to(env.device)


def env_frames(env: BatchedEnv, render_mode: str | None):
    """The frames behind ``render()`` for ``render_mode`` ('rgb_array' or None: nothing is drawn)."""
    if render_mode is None:
        return None
    if render_mode != "rgb_array":
        raise ValueError(f"render_mode {render_mode!r} is not supported; use 'rgb_array' (or None)")
    from ..viz.frames import EnvFrames

    return EnvFrames(env)


_IMPORTED_IN = os.getpid()
"""The process that imported this module (a process forked from it inherits the number)."""


def one_thread_if_forked():
    """In a process forked from the one that imported this module (the workers of gymnasium's async vector env, by
    default on Linux), torch runs on one thread: the parent's OpenMP threads do not survive a fork, and the first
    parallel torch op in the child (a camera env's frames are large enough) would wait for them forever."""
    if os.getpid() != _IMPORTED_IN:
        import torch

        torch.set_num_threads(1)


def check_keywords(owner: str, overrides: dict):
    """TypeError for a keyword that is no env-config section: Python's and gymnasium's answer to an unexpected
    keyword argument, on which clients retry without it (TorchRL's ``GymEnv`` drops ``frameskip`` on a TypeError)."""
    sections = {f.name for f in dataclasses.fields(EnvConfig)} - {"num_envs", "device", "seed"}
    unknown = sorted(set(overrides) - sections - {"num_envs"})
    if unknown:
        raise TypeError(f"{owner}() got an unexpected keyword argument {unknown[0]!r} (beside the named arguments, "
                        f"the env config's sections: {', '.join(sorted(sections))})")


def render_metadata(env: BatchedEnv) -> dict:
    """``render_modes`` and ``render_fps`` (one frame per env step) for an env's metadata."""
    return {"render_modes": ["rgb_array"], "render_fps": round(1.0 / env.env_dt)}


def env_ids() -> dict[str, tuple[str, str | None]]:
    """Every registered task's gymnasium ids: id -> (task name, preset). None sets ``max_episode_steps``: the env
    truncates by itself (at its time limit) or never (the ``tutorial`` preset, like the Isaac Sim tutorial)."""
    return {env_id: (name, preset) for name in tasks.names() for env_id, preset in tasks.get(name).gym_ids.items()}


def register_envs() -> None:
    """Register ``env_ids()`` with gymnasium (idempotent); ``import cartpole_warp`` calls it."""
    for env_id, (task, preset) in env_ids().items():
        if env_id not in gym.registry:
            gym.register(
                id=env_id,
                entry_point="cartpole_warp.wrappers.gymnasium:TaskGymEnv",
                vector_entry_point="cartpole_warp.wrappers.gymnasium:TaskVectorEnv",
                kwargs={"task_name": task, "preset": preset},
            )


class TaskGymEnv(gym.Env):
    """One env of a task as a ``gymnasium.Env`` (the task's ``BatchedEnv`` with ``num_envs=1``).

    ``step`` returns the observation at which an episode ends, ``reset`` starts the next one. After an ending
    step, ``reset()`` without a seed continues from the reset state the env already sampled, so the trajectory
    equals that of the batched env with ``num_envs=1``, the same seed and actions. ``reset(seed=s)`` re-seeds the
    env's RNG. Stepping past an ending step without ``reset`` continues in the next episode.
    ``info`` on an ending step: ``episode_return``, ``episode_length`` and ``end_reason`` (a name).

    Arguments: ``task_name`` (a registered task), ``preset`` (a name under configs/, a YAML path or None: the task's
    defaults), ``device``, ``seed`` (the RNG seed until ``reset(seed=...)``; default the preset's) and
    ``tasks.make``'s nested overrides of the env config, e.g. ``task={...}`` (the task's settings).
    """

    metadata = {"render_modes": ["rgb_array"]}

    def __init__(self, task_name: str = tasks.DEFAULT_TASK, preset: str | None = None, device: str = "cpu",
                 seed: int | None = None, render_mode: str | None = None, **overrides):
        check_keywords(type(self).__name__, overrides)
        one_thread_if_forked()
        if "num_envs" in overrides:
            raise ValueError(f"{task_name}'s gymnasium env is one env; for {overrides['num_envs']} use "
                             "gym.make_vec(id, num_envs=N, vectorization_mode='vector_entry_point')")
        self.env = tasks.make(task_name, num_envs=1, device=device, seed=seed, preset=preset, **overrides)
        self.render_mode = render_mode
        self.metadata = {**self.metadata, **render_metadata(self.env)}
        self._frames = env_frames(self.env, render_mode)
        self.observation_space = self.env.single_observation_space
        self.action_space = self.env.single_action_space
        self._episode_ended = False

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None):
        super().reset(seed=seed)
        if seed is None and self._episode_ended:
            obs = self.env.get_observations()
        else:
            obs, _ = self.env.reset(seed=seed)
        self._episode_ended = False
        return obs[0].cpu().numpy(), {}

    def step(self, action):
        obs, reward, terminated, truncated, info = self.env.step(actions_tensor(action, 1, self.env))
        terminated, truncated = bool(terminated[0]), bool(truncated[0])
        self._episode_ended = terminated or truncated
        step_info = {}
        if self._episode_ended:
            obs = info["final_obs"]
            step_info = {
                "episode_return": float(info["episode_return"][0]),
                "episode_length": int(info["episode_length"][0]),
                "end_reason": self.env.end_reasons[int(info["end_reason"][0])],
            }
        return obs[0].cpu().numpy(), float(reward[0]), terminated, truncated, step_info

    def render(self):
        """With ``render_mode="rgb_array"``: the cartpole now, (H, W, 3) uint8, side-on (play.py's pictures)."""
        return self._frames[0] if self._frames is not None else None

    def close(self):
        self.env.close()

    core = renamed_attribute("core", "env")


class TaskVectorEnv(VectorEnv):
    """A task's ``BatchedEnv`` as a ``gymnasium.vector.VectorEnv`` (numpy in and out, no loop over envs).

    Same-step autoreset (``metadata["autoreset_mode"]``): an env that ends returns the first observation of
    its next episode. On steps where any env ended, ``info`` holds (gymnasium 1.x convention):

    - ``final_obs`` (N, num_obs) float32 (or camera frames: ``observation_space``), the observations at which
      episodes ended, valid where ``_final_obs`` (N,) bool;
    - ``final_info`` {``episode_return``, ``episode_length``, ``end_reason`` (codes of the env's ``end_reasons``),
      each with its ``_key`` mask}, valid where ``_final_info``.

    Arguments as for ``TaskGymEnv``, plus ``num_envs`` (default the preset's); ``preset`` defaults to None.
    """

    metadata = {"autoreset_mode": AutoresetMode.SAME_STEP, "render_modes": ["rgb_array"]}

    def __init__(self, num_envs: int | None = None, task_name: str = tasks.DEFAULT_TASK, preset: str | None = None,
                 device: str = "cpu", seed: int | None = None, render_mode: str | None = None, **overrides):
        check_keywords(type(self).__name__, overrides)
        one_thread_if_forked()
        self.env = tasks.make(task_name, num_envs=num_envs, device=device, seed=seed, preset=preset, **overrides)
        self.render_mode = render_mode
        self.metadata = {**self.metadata, **render_metadata(self.env)}
        self._frames = env_frames(self.env, render_mode)
        self.num_envs = self.env.num_envs
        self.autoreset_mode = self.metadata["autoreset_mode"]
        """As gymnasium's own vector envs have it (clients read the attribute, not the metadata)."""
        self.single_observation_space = self.env.single_observation_space
        self.single_action_space = self.env.single_action_space
        self.observation_space, self.action_space = self.env.observation_space, self.env.action_space

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None):
        super().reset(seed=seed)
        obs, _ = self.env.reset(seed=seed)
        return obs.cpu().numpy(), {}

    def step(self, actions):
        obs, reward, terminated, truncated, info = self.env.step(
            actions_tensor(actions, self.num_envs, self.env))
        terminated, truncated = terminated.cpu().numpy(), truncated.cpu().numpy()
        done = terminated | truncated
        infos = {}
        if done.any():
            final_info = {}
            for key in ("episode_return", "episode_length", "end_reason"):
                final_info[key] = info[key].cpu().numpy()
                final_info[f"_{key}"] = done
            infos = {"final_obs": info["final_obs"].cpu().numpy(), "_final_obs": done,
                     "final_info": final_info, "_final_info": done}
        return obs.cpu().numpy(), reward.cpu().numpy(), terminated, truncated, infos

    def render(self):
        """With ``render_mode="rgb_array"``: a sequence of ``num_envs`` frames (H, W, 3) uint8 that draws env ``i``
        only when ``frames[i]`` is read, so ``RecordVideo(envs, ..., record_first_only=True)`` costs one picture a
        step (without it, RecordVideo reads and tiles all envs: keep num_envs small then)."""
        return self._frames

    def close_extras(self, **kwargs):
        self.env.close()

    core = renamed_attribute("core", "env")

__getattr__ = renamed(__name__, {"CartpoleGymEnv": "TaskGymEnv", "CartpoleVectorEnv": "TaskVectorEnv"})
"""The old names (before they said what they serve), until ``settings.deprecation.REMOVED_IN``."""
