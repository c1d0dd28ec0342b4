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


def autoreset_mode_of(mode: AutoresetMode | str) -> AutoresetMode:
    """``mode`` as an ``AutoresetMode``; ValueError for any but same-step and next-step (the batched env resets the
    envs that end: it cannot leave them ended)."""
    offered = (AutoresetMode.SAME_STEP, AutoresetMode.NEXT_STEP)
    try:
        chosen = AutoresetMode(mode)
    except ValueError:
        chosen = None
    if chosen not in offered:
        raise ValueError(f"autoreset_mode must be one of {', '.join(repr(m.value) for m in offered)} "
                         f"(AutoresetMode.SAME_STEP or NEXT_STEP), got {mode!r}")
    return chosen


def episode_ends(info: dict, ended: np.ndarray) -> dict[str, np.ndarray]:
    """The ended episodes' figures of a batched env's ``info`` (return, length, end reason code), each with its
    ``_key`` mask ``ended``."""
    ends = {}
    for key in ("episode_return", "episode_length", "end_reason"):
        ends[key] = info[key].cpu().numpy()
        ends[f"_{key}"] = ended
    return ends


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

    ``autoreset_mode`` (also in ``metadata``), gymnasium's two:

    - ``SAME_STEP`` (the default; the batched env's own): an env that ends returns the first observation of its next
      episode. On steps where any env ended, ``info`` holds (gymnasium 1.x convention) ``final_obs`` (N, num_obs)
      float32 (or camera frames: ``observation_space``), the observations at which episodes ended, valid where
      ``_final_obs`` (N,) bool; and ``final_info`` {``episode_return``, ``episode_length``, ``end_reason`` (codes of the
      env's ``end_reasons``), each with its ``_key`` mask}, valid where ``_final_info``.
    - ``NEXT_STEP`` (gymnasium's default, which its vector observation wrappers require): an env that ends returns the
      observation at which it ended, with ``info`` {``episode_return``, ``episode_length``, ``end_reason``, each with
      its ``_key`` mask}; its next step ignores its action and returns the first observation of its next episode,
      reward 0, neither terminated nor truncated. Its trajectory is a ``SyncVectorEnv``'s of ``TaskGymEnv`` (checked
      without observation noise: with it, the restarted envs draw their noise on from elsewhere in their stream).

    Arguments as for ``TaskGymEnv``, plus ``num_envs`` (default the preset's) and ``autoreset_mode`` (an
    ``AutoresetMode`` or its value, e.g. ``"NextStep"``); ``preset`` defaults to None.
    """

    metadata = {"autoreset_mode": AutoresetMode.SAME_STEP, "render_modes": ["rgb_array"]}

    def __init__(self, num_envs: int | None = None, task_name: str = tasks.DEFAULT_TASK, preset: str | None = None,
                 device: str = "cpu", seed: int | None = None, render_mode: str | None = None,
                 autoreset_mode: AutoresetMode | str = AutoresetMode.SAME_STEP, **overrides):
        check_keywords(type(self).__name__, overrides)
        self.autoreset_mode = autoreset_mode_of(autoreset_mode)
        """As gymnasium's own vector envs have it (clients read the attribute, not the metadata)."""
        one_thread_if_forked()
        self.env = tasks.make(task_name, num_envs=num_envs, device=device, seed=seed, preset=preset, **overrides)
        self.render_mode = render_mode
        self.metadata = {**self.metadata, **render_metadata(self.env), "autoreset_mode": self.autoreset_mode}
        self._frames = env_frames(self.env, render_mode)
        self.num_envs = self.env.num_envs
        self._restart: tuple[torch.Tensor, torch.Tensor, torch.Tensor] | None = None
        """``NEXT_STEP``: the envs whose episode ended last step, their next episode's start states and observations."""
        self.single_observation_space = self.env.single_observation_space
        self.single_action_space = self.env.single_action_space
        self.observation_space, self.action_space = self.env.observation_space, self.env.action_space

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None):
        super().reset(seed=seed)
        obs, _ = self.env.reset(seed=seed)
        self._restart = None
        return obs.cpu().numpy(), {}

    def step(self, actions):
        obs, reward, terminated, truncated, info = self.env.step(
            actions_tensor(actions, self.num_envs, self.env))
        if self.autoreset_mode == AutoresetMode.NEXT_STEP:
            return self._next_step_autoreset(obs, reward, terminated, truncated, info)
        terminated, truncated = terminated.cpu().numpy(), truncated.cpu().numpy()
        done = terminated | truncated
        infos = {}
        if done.any():
            infos = {"final_obs": info["final_obs"].cpu().numpy(), "_final_obs": done,
                     "final_info": episode_ends(info, done), "_final_info": done}
        return obs.cpu().numpy(), reward.cpu().numpy(), terminated, truncated, infos

    def _next_step_autoreset(self, obs, reward, terminated, truncated, info):
        """``step``'s results under ``NEXT_STEP`` from the batched env's same-step ones: the envs that ended last step
        go back to the start of the episode the batched env began for them (stepping them was a throw-away step),
        the envs that end now return their final observation."""
        import torch

        if self._restart is not None:
            restarting, states, first_obs = self._restart
            self.env.set_state(states, restarting)
            obs = torch.where(restarting.view(-1, *[1] * (obs.dim() - 1)), first_obs, obs)
            reward = torch.where(restarting, 0.0, reward)
            terminated, truncated = terminated & ~restarting, truncated & ~restarting
        ended = terminated | truncated
        self._restart = None
        infos = {}
        if ended.any():
            q, qd = self.env.joint_state()
            self._restart = (ended, torch.stack([q, qd], dim=2).flatten(1), obs.clone())
            obs = torch.where(ended.view(-1, *[1] * (obs.dim() - 1)), info["final_obs"], obs)
            infos = episode_ends(info, ended.cpu().numpy())
        return obs.cpu().numpy(), reward.cpu().numpy(), terminated.cpu().numpy(), truncated.cpu().numpy(), infos

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
