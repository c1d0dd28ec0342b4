"""rsl-rl ``VecEnv`` adapter for any task's ``BatchedEnv`` (rsl-rl-lib 5.5).

    from rsl_rl.runners import OnPolicyRunner
    env = RslRlVecEnv(cartpole_warp.tasks.make("cartpole-swingup", num_envs=4096))
    runner = OnPolicyRunner(env, train_cfg, log_dir, device=env.device)
"""

from __future__ import annotations

from . import tensordict_import  # noqa: F401  (first: rsl-rl's tensordict without torch._dynamo)

# isort: split
import torch
from rsl_rl.env import VecEnv
from tensordict import TensorDict

from ..engine.env import BatchedEnv
from ..evaluation.in_step import InStepEvaluation


class RslRlVecEnv(VecEnv):
    """Presents a ``BatchedEnv`` as an rsl-rl ``VecEnv``, without waiting for the device.

    Observations are ``TensorDict({"policy": (N, num_obs)})``, or where the env's policy sees camera frames
    ``TensorDict({"policy": frames (N, C, H, W), "critic": the task's state (N, num_obs)})`` (``images``);
    ``dones`` is terminated | truncated (int64); ``extras["time_outs"]`` marks truncations so PPO bootstraps them.
    ``extras`` also carries the env's ``info`` (``episode_return``, ``episode_length``, ``end_reason``,
    ``final_obs``: valid where ``dones``), from which a training loop can keep episode statistics without indexing or
    a host sync per step. The observations are fresh tensors (rsl-rl's PPO keeps them until after the next step);
    the rewards, ``time_outs`` and the ``info`` tensors are the env's views (``BatchedEnv.step_views``), which the next
    step overwrites: rsl-rl uses them at once, and a loop that keeps them clones them.

    With an ``evaluation`` (``InStepEvaluation``: the env's last envs) rsl-rl sees only the envs before it; each step
    steps the evaluation's envs too, with the evaluation's actions, and hands it their results.
    """

    def __init__(self, env: BatchedEnv, evaluation: InStepEvaluation | None = None):
        self.env, self.evaluation = env, evaluation
        self.num_envs = env.num_envs if evaluation is None else evaluation.start
        self.num_actions = env.num_actions
        self.max_episode_length = env.max_episode_length
        self.device = env.device
        self.cfg = env.cfg
        self.images = env.sees_images
        """The policy observes camera frames (and the critic the task's state)."""
        self.obs_mirror, self.action_mirror = (
            torch.tensor(signs, dtype=torch.float32, device=env.device) if signs is not None and not self.images
            else None for signs in (env.obs_mirror, env.action_mirror))
        """The task's mirror signs (``BatchedEnv.obs_mirror``, ``action_mirror``) as tensors on the device (None: the
        task has no symmetry, or the policy sees images, which the signs do not mirror)."""

    @property
    def episode_length_buf(self) -> torch.Tensor:
        """(N,) env steps into the current episodes; assigning copies into the env's buffer."""
        return self.env.episode_length_buf[:self.num_envs]

    @episode_length_buf.setter
    def episode_length_buf(self, value: torch.Tensor):
        self.env.episode_length_buf[:self.num_envs] = value

    def _wrap(self, obs: torch.Tensor) -> TensorDict:
        n = self.num_envs
        groups = {"policy": obs[:n]} | ({"critic": self.env.get_state_observations()[:n]} if self.images else {})
        return TensorDict(groups, batch_size=[n], device=self.device)

    def get_observations(self) -> TensorDict:
        """Current observations as ``TensorDict({"policy": (N, num_obs)})``."""
        return self._wrap(self.env.get_observations())

    def step(self, actions: torch.Tensor) -> tuple[TensorDict, torch.Tensor, torch.Tensor, dict]:
        """One env step: (obs, rewards (N,), dones (N,), extras)."""
        n, evaluation, actions = self.num_envs, self.evaluation, actions.to(torch.float32)
        if evaluation is not None:
            actions = torch.cat([actions.reshape(n, -1), evaluation.actions()])
        obs, reward, terminated, truncated, info = self.env.step_views(actions)
        obs = obs.clone()
        if evaluation is not None:
            evaluation.after_step(obs[n:], reward[n:], terminated[n:], truncated[n:])
            reward, terminated, truncated = reward[:n], terminated[:n], truncated[:n]
            info = {key: value[:n] if value.dim() else value for key, value in info.items()}
        return self._wrap(obs), reward, (terminated | truncated).long(), {"time_outs": truncated, **info}

    def close(self):
        self.env.close()


def mirror(env: RslRlVecEnv, obs: TensorDict | None = None, actions: torch.Tensor | None = None,
           ) -> tuple[TensorDict | None, torch.Tensor | None]:
    """rsl-rl's symmetry ``data_augmentation_func`` for any task with a mirror: each batch followed by its mirror
    image (``obs_mirror`` and ``action_mirror`` signs), device work only (it runs inside captured updates)."""
    if obs is not None:
        obs = torch.cat([obs, obs.apply(lambda values: values * env.obs_mirror)])
    if actions is not None:
        actions = torch.cat([actions, actions * env.action_mirror])
    return obs, actions
