"""Episode statistics, summed on the device, and the one definition of "solved"."""

from __future__ import annotations

from dataclasses import dataclass

import torch

from .distributed import all_reduce_sum

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
    """Sums over finished episodes, kept on the device: ``add`` never waits for the device, ``pop`` reads once."""

    def __init__(self, device: str | torch.device = "cpu"):
        self._sums = torch.zeros(5, dtype=torch.float64, device=device)
        """episodes, returns, lengths, rewards per step, episodes that reached the time limit."""

    def add(self, ended: torch.Tensor, returns: torch.Tensor, lengths: torch.Tensor, timed_out: torch.Tensor):
        """Count the episodes where ``ended`` (N,) bool: their returns, lengths (env steps) and whether they reached
        the time limit; the values where ``ended`` is False are ignored."""
        lengths, returns = lengths.to(torch.float64), returns.to(torch.float64)
        values = torch.stack((torch.ones_like(returns), returns, lengths, returns / lengths.clamp(min=1),
                              timed_out.to(torch.float64)))
        self._sums += torch.where(ended, values, 0.0).sum(dim=1)

    def summary(self) -> EpisodeSummary:
        """Means over the episodes counted so far (one read from the device)."""
        count, returns, lengths, per_step, timed_out = self._sums.tolist()
        if count == 0:
            return EpisodeSummary(0, None, None, None, None)
        return EpisodeSummary(int(count), returns / count, lengths / count, per_step / count, timed_out / count)

    def pop(self, all_processes: bool = False) -> EpisodeSummary:
        """The summary so far (``all_processes``: over the episodes of every process of a torchrun job); then start
        afresh."""
        all_reduce_sum(self._sums, all_processes)
        result = self.summary()
        self._sums.zero_()
        return result
