"""Running a policy on the batched env: trained, zero or random policies, and the statistics of a rollout.

A policy is any ``policy(obs) -> actions`` callable on torch tensors, obs (N, 4) -> actions (N, 1) in [-1, 1].
"""

from __future__ import annotations

from collections.abc import Callable

import torch

from ..env import CartpoleEnv
from .metrics import EpisodeStats, EpisodeSummary

Policy = Callable[[torch.Tensor], torch.Tensor]
"""``policy(obs (N, 4)) -> actions (N, 1)``, torch tensors on one device."""


def zero_policy(obs: torch.Tensor) -> torch.Tensor:
    """Never pushes the cart."""
    return torch.zeros(obs.shape[0], 1, dtype=torch.float32, device=obs.device)


def random_policy(seed: int = 0) -> Policy:
    """Uniform random actions in [-1, 1] from a seeded generator."""
    generator = torch.Generator().manual_seed(seed)

    def policy(obs: torch.Tensor) -> torch.Tensor:
        return (torch.rand(obs.shape[0], 1, generator=generator) * 2 - 1).to(obs.device)

    return policy


def rollout(env: CartpoleEnv, policy: Policy, steps: int, on_step: Callable[[int], None] | None = None
            ) -> EpisodeSummary:
    """Reset ``env`` and run ``policy`` for ``steps`` env steps without gradients; ``on_step(k)`` is called after
    the reset (k = 0) and after each step k (to record pictures).

    Statistics cover each env's first episode; an episode still running after ``steps`` counts as having reached
    the time limit (the run's step cap), which only happens when ``steps`` < max_episode_length.
    """
    obs, _ = env.reset()
    if on_step is not None:
        on_step(0)
    stats = EpisodeStats(env.device)
    finished = torch.zeros(env.num_envs, dtype=torch.bool, device=env.device)
    returns = torch.zeros(env.num_envs, dtype=torch.float32, device=env.device)
    with torch.inference_mode():
        for step in range(1, steps + 1):
            obs, reward, terminated, truncated, _ = env.step(policy(obs).to(torch.float32))
            returns += torch.where(finished, 0.0, reward)
            ended = (terminated | truncated) & ~finished
            stats.add(ended, returns, torch.full_like(returns, step), truncated)
            finished |= ended
            if on_step is not None:
                on_step(step)
        stats.add(~finished, returns, torch.full_like(returns, steps), torch.ones_like(finished))
    return stats.summary()
