"""rsl-rl ``VecEnv`` adapter for ``CartpoleEnv`` (rsl-rl-lib 5.5).

    from rsl_rl.runners import OnPolicyRunner
    env = RslRlVecEnv(cartpole_warp.make_env(num_envs=4096))
    runner = OnPolicyRunner(env, train_cfg, log_dir, device=env.device)
"""

from __future__ import annotations

import torch
from rsl_rl.env import VecEnv
from tensordict import TensorDict

from .env import CartpoleEnv
from .metrics import EpisodeStats


class RslRlVecEnv(VecEnv):
    """Presents a ``CartpoleEnv`` as an rsl-rl ``VecEnv``.

    Observations are ``TensorDict({"policy": (N, 4)})``; ``dones`` is terminated | truncated (int64);
    ``extras["time_outs"]`` marks truncations so PPO bootstraps them; ``extras["episode"]`` carries the finished
    episodes' ``return``, ``length`` (env steps), ``reward_per_step`` and ``time_limit_fraction`` for rsl-rl's logger.
    Every finished episode is also added to ``episode_stats`` (pop it once per iteration).
    """

    def __init__(self, env: CartpoleEnv):
        self.env = env
        self.num_envs = env.num_envs
        self.num_actions = env.num_actions
        self.max_episode_length = env.max_episode_length
        self.device = env.device
        self.cfg = env.cfg
        self.episode_stats = EpisodeStats()

    @property
    def episode_length_buf(self) -> torch.Tensor:
        """(N,) env steps into the current episodes; assigning copies into the env's buffer."""
        return self.env.episode_length_buf

    @episode_length_buf.setter
    def episode_length_buf(self, value: torch.Tensor):
        self.env.episode_length_buf = value

    def _wrap(self, obs: torch.Tensor) -> TensorDict:
        return TensorDict({"policy": obs}, batch_size=[self.num_envs], device=self.device)

    def get_observations(self) -> TensorDict:
        """Current observations as ``TensorDict({"policy": (N, 4)})``."""
        return self._wrap(self.env.get_observations())

    def step(self, actions: torch.Tensor) -> tuple[TensorDict, torch.Tensor, torch.Tensor, dict]:
        """One env step: (obs, rewards (N,), dones (N,), extras)."""
        obs, reward, terminated, truncated, info = self.env.step(actions.to(torch.float32))
        ended = terminated | truncated
        extras = {"time_outs": truncated, "episode": {}}
        if ended.any():
            returns, lengths = info["episode_return"][ended], info["episode_length"][ended].float()
            timed_out = truncated[ended].float()
            extras["episode"] = {
                "return": returns,
                "length": lengths,
                "reward_per_step": returns / lengths.clamp(min=1),
                "time_limit_fraction": timed_out,
            }
            self.episode_stats.add(returns, lengths, timed_out)
        return self._wrap(obs), reward, ended.long(), extras
