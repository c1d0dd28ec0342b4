"""Episode statistics and the one definition of "solved"."""

from __future__ import annotations

from dataclasses import dataclass

import torch

SOLVED_LENGTH_FRACTION = 0.95
"""Solved needs a mean episode length of at least this fraction of the time limit ..."""
SOLVED_REWARD_PER_STEP = 0.9
"""... and a mean reward per step (episode return / episode length) of at least this."""


def is_solved(mean_episode_length: float | None, mean_reward_per_step: float | None, max_episode_length: int) -> bool:
    """The cartpole is solved when finished episodes last >= 95% of the time limit (env steps) on average
    and earn >= 0.9 reward per step on average."""
    if mean_episode_length is None or mean_reward_per_step is None:
        return False
    return (mean_episode_length >= SOLVED_LENGTH_FRACTION * max_episode_length
            and mean_reward_per_step >= SOLVED_REWARD_PER_STEP)


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


class EpisodeStats:
    """Accumulates finished episodes (return, length, reached time limit) until ``pop``."""

    def __init__(self):
        self._returns: list[torch.Tensor] = []
        self._lengths: list[torch.Tensor] = []
        self._timeouts: list[torch.Tensor] = []

    def add(self, returns: torch.Tensor, lengths: torch.Tensor, timed_out: torch.Tensor):
        """Record finished episodes: returns, lengths (env steps) and whether each reached the time limit (1-D)."""
        self._returns.append(returns.float().cpu())
        self._lengths.append(lengths.float().cpu())
        self._timeouts.append(timed_out.float().cpu())

    def summary(self) -> EpisodeSummary:
        """Means over the episodes recorded so far."""
        returns = torch.cat(self._returns) if self._returns else torch.zeros(0)
        if returns.numel() == 0:
            return EpisodeSummary(0, None, None, None, None)
        lengths = torch.cat(self._lengths)
        return EpisodeSummary(
            episodes=returns.numel(),
            mean_return=returns.mean().item(),
            mean_length=lengths.mean().item(),
            mean_reward_per_step=(returns / lengths.clamp(min=1)).mean().item(),
            time_limit_fraction=torch.cat(self._timeouts).mean().item(),
        )

    def pop(self) -> EpisodeSummary:
        """The summary so far; then start afresh."""
        result = self.summary()
        self.__init__()
        return result
