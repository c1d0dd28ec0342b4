"""Episode statistics summed on the device, and running a policy on a batched env: trained, zero or random policies.

A policy is any ``policy(obs) -> actions`` callable on torch tensors, obs (N, num_obs) -> actions (N, num_actions).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import torch

from .env import BatchedEnv

NO_LIMIT_STEPS = 1000
"""Env steps an evaluation or play runs where the task has no time limit."""
Policy = Callable[[torch.Tensor], torch.Tensor]
"""``policy(obs (N, num_obs)) -> actions (N, num_actions)``, torch tensors on one device."""


@dataclass
class EpisodeSummary:
    """Means over a set of finished episodes (None where no episode finished)."""

    episodes: int
    mean_return: float | None
    mean_length: float | None
    """Env steps."""
    mean_reward_per_step: float | None
    time_limit_fraction: float | None
    """Fraction of the episodes that reached the time limit instead of failing."""
    full_episodes: int = 0
    """Episodes that ran the whole time limit (the first episodes of a run with random episode starts are shorter)."""
    full_reward_per_step: float | None = None
    """Mean reward per step of the full episodes."""


class EpisodeStats:
    """Sums over finished episodes, kept on the device: ``add`` never waits for the device, ``pop`` reads once.
    An episode is full when it ran ``max_episode_length`` steps."""

    def __init__(self, device: str | torch.device, max_episode_length: int):
        self.max_episode_length = max_episode_length
        self._sums = torch.zeros(7, dtype=torch.float64, device=device)
        """episodes, returns, lengths, rewards per step, episodes that reached the time limit, full episodes, their
        rewards per step."""

    def add(self, ended: torch.Tensor, returns: torch.Tensor, lengths: torch.Tensor, timed_out: torch.Tensor):
        """Count the episodes where ``ended`` (N,) bool: their returns, lengths (env steps) and whether they reached
        the time limit; the values where ``ended`` is False are ignored."""
        lengths, returns = lengths.to(torch.float64), returns.to(torch.float64)
        per_step = returns / lengths.clamp(min=1)
        full = (lengths >= self.max_episode_length).to(torch.float64)
        values = torch.stack((torch.ones_like(returns), returns, lengths, per_step, timed_out.to(torch.float64), full,
                              full * per_step))
        self._sums += torch.where(ended, values, 0.0).sum(dim=1)

    def summary(self) -> EpisodeSummary:
        """Means over the episodes counted so far (one read from the device)."""
        count, returns, lengths, per_step, timed_out, full, full_per_step = self._sums.tolist()
        if count == 0:
            return EpisodeSummary(0, None, None, None, None)
        return EpisodeSummary(int(count), returns / count, lengths / count, per_step / count, timed_out / count,
                              int(full), full_per_step / full if full else None)

    def pop(self, all_processes: bool = False) -> EpisodeSummary:
        """The summary so far (``all_processes``: summed over the processes of a torchrun job first); then start
        afresh."""
        if all_processes:
            torch.distributed.all_reduce(self._sums, op=torch.distributed.ReduceOp.SUM)
        result = self.summary()
        self._sums.zero_()
        return result


def zero_policy(obs: torch.Tensor, num_actions: int = 1) -> torch.Tensor:
    """Never acts."""
    return torch.zeros(obs.shape[0], num_actions, dtype=torch.float32, device=obs.device)


def random_policy(num_actions: int, seed: int = 0) -> Policy:
    """Uniform random actions in [-1, 1] from a seeded generator."""
    generator = torch.Generator().manual_seed(seed)

    def policy(obs: torch.Tensor) -> torch.Tensor:
        return (torch.rand(obs.shape[0], num_actions, generator=generator) * 2 - 1).to(obs.device)

    return policy


@dataclass
class FirstEpisodes:
    """Each env's first episode in a run: (N,) tensors on the env's device."""

    returns: torch.Tensor
    lengths: torch.Tensor
    """Env steps (the run's step cap for an episode still running at its end)."""
    reached_limit: torch.Tensor
    """bool: the episode reached the time limit (or the step cap) instead of failing."""

    def summary(self, max_episode_length: int) -> EpisodeSummary:
        """Means over the episodes (full: those of ``max_episode_length`` steps)."""
        stats = EpisodeStats(self.returns.device, max_episode_length)
        stats.add(torch.ones_like(self.reached_limit), self.returns, self.lengths, self.reached_limit)
        return stats.summary()


def first_episodes(env: BatchedEnv, policy: Policy, steps: int, on_step: Callable[[int], None] | None = None,
                   reset: bool = True, seed: int | None = None) -> FirstEpisodes:
    """Reset ``env`` (re-seeded with ``seed`` where given: the same starts each time; unless ``reset`` is False: the
    episodes it has just begun) and run ``policy`` for ``steps`` env steps without gradients; ``on_step(k)`` is called
    after the reset (k = 0) and after each step k (to record pictures). An episode still running after ``steps``
    counts as having reached the time limit."""
    obs = env.reset(seed)[0] if reset else env.get_observations()
    if on_step is not None:
        on_step(0)
    finished = torch.zeros(env.num_envs, dtype=torch.bool, device=env.device)
    reached = torch.ones_like(finished)
    lengths = torch.full((env.num_envs,), steps, dtype=torch.int64, device=env.device)
    returns = torch.zeros(env.num_envs, dtype=torch.float32, device=env.device)
    with torch.inference_mode():
        for step in range(1, steps + 1):
            obs, reward, terminated, truncated, _ = env.step(policy(obs).to(torch.float32))
            returns += torch.where(finished, 0.0, reward)
            ended = (terminated | truncated) & ~finished
            lengths = torch.where(ended, step, lengths)
            reached = torch.where(ended, truncated, reached)
            finished |= ended
            if on_step is not None:
                on_step(step)
    return FirstEpisodes(returns, lengths, reached)


def rollout(env: BatchedEnv, policy: Policy, steps: int, on_step: Callable[[int], None] | None = None,
            seed: int | None = None) -> EpisodeSummary:
    """``first_episodes`` summarised: statistics over each env's first episode; an episode still running after
    ``steps`` counts as full (the run's step cap), which only happens when ``steps`` < max_episode_length."""
    return first_episodes(env, policy, steps, on_step, seed=seed).summary(min(steps, env.max_episode_length))


def whole_episode_steps(env: BatchedEnv) -> int:
    """Env steps that play every first episode to its end: the time limit, or NO_LIMIT_STEPS without one."""
    return env.max_episode_length if env.cfg.task.episode_length_s is not None else NO_LIMIT_STEPS


def evaluate(env: BatchedEnv, policy: Policy, seed: int) -> EpisodeSummary:
    """Each env's first episode from a reset seeded with ``seed`` to its end (``whole_episode_steps``): what
    ``play.py --headless`` plays with that env count and seed (the evaluation that decides 'solved')."""
    return rollout(env, policy, whole_episode_steps(env), seed=seed)
