"""Episode statistics: the means over a set of finished episodes (``EpisodeSummary``, whose field names are the names
used everywhere: progress history, summary.json, play's result, a task's ``play_metric``) and their sums kept on the
device (``EpisodeStats``), and the rule that judges them (``SolvedRule``, each task's). Below the tasks; torch is
imported where it is used, so the registry loads without it.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    import torch


@dataclass
class EpisodeSummary:
    """Means over a set of finished episodes (None where no episode finished)."""

    episodes: int
    mean_return: float | None
    mean_episode_length: float | None
    """Env steps."""
    mean_reward_per_step: float | None
    time_limit_fraction: float | None
    """Fraction of the episodes that reached the time limit instead of failing."""
    full_episodes: int = 0
    """Episodes that ran the whole time limit (the first episodes of a run with random episode starts are shorter)."""
    full_reward_per_step: float | None = None
    """Mean reward per step of the full episodes."""
    cut_at_step: int | None = None
    """Where an evaluation stopped at this env step, once its failed episodes kept the task's rule from being met
    (``SolvedRule.hopeless``): the means are over the episodes that had ended (None: a whole run)."""


class EpisodeStats:
    """Sums over finished episodes, kept on the device: ``add`` never waits for the device, ``pop`` reads once.
    An episode is full when it ran ``max_episode_length`` steps. With ``groups`` the envs are that many equal blocks
    (a population's members), each summed apart (``take``)."""

    def __init__(self, device: str | torch.device, max_episode_length: int, groups: int = 1):
        import torch

        self.max_episode_length = max_episode_length
        self._sums = torch.zeros(groups, 7, dtype=torch.float64, device=device)
        """Per group: episodes, returns, lengths, rewards per step, episodes that reached the time limit, full
        episodes, their rewards per step."""

    def add(self, ended: torch.Tensor, returns: torch.Tensor, lengths: torch.Tensor, timed_out: torch.Tensor):
        """Count the episodes where ``ended`` (N,) bool: their returns, lengths (env steps) and whether they reached
        the time limit; the values where ``ended`` is False are ignored."""
        import torch

        lengths, returns = lengths.to(torch.float64), returns.to(torch.float64)
        per_step = returns / lengths.clamp(min=1)
        full = (lengths >= self.max_episode_length).to(torch.float64)
        values = torch.stack((torch.ones_like(returns), returns, lengths, per_step, timed_out.to(torch.float64), full,
                              full * per_step))
        self._sums += torch.where(ended, values, 0.0).view(7, len(self._sums), -1).sum(dim=2).T

    def summary(self) -> EpisodeSummary:
        """Means over the episodes counted so far, every group's (one read from the device)."""
        return summary_of(self._sums.sum(dim=0).tolist())

    def take(self) -> torch.Tensor:
        """The sums so far, (groups, 7) on the device (``summary_of`` a row on the host), then start afresh (device
        work only)."""
        sums = self._sums.clone()
        self._sums.zero_()
        return sums

    def pop(self, all_processes: bool = False) -> EpisodeSummary:
        """The summary so far (``all_processes``: summed over the processes of a torchrun job first); then start
        afresh."""
        if all_processes:
            import torch

            torch.distributed.all_reduce(self._sums, op=torch.distributed.ReduceOp.SUM)
        result = self.summary()
        self._sums.zero_()
        return result


def summary_of(sums: list[float]) -> EpisodeSummary:
    """The means of one group's sums (``EpisodeStats``: episodes, returns, lengths, rewards per step, episodes that
    reached the time limit, full episodes, their rewards per step)."""
    count, returns, lengths, per_step, timed_out, full, full_per_step = sums
    if count == 0:
        return EpisodeSummary(0, None, None, None, None)
    return EpisodeSummary(int(count), returns / count, lengths / count, per_step / count, timed_out / count,
                          int(full), full_per_step / full if full else None)


METRICS = tuple(f.name for f in dataclasses.fields(EpisodeSummary) if f.type == "float | None")
"""The ``EpisodeSummary`` fields that are means (a task's ``play_metric`` names one)."""
METRIC_LABELS = {"mean_return": "mean return", "mean_episode_length": "mean episode length (steps)",
                 "mean_reward_per_step": "mean reward per step",
                 "time_limit_fraction": "episodes reaching the time limit",
                 "full_reward_per_step": "mean reward per step of full-length episodes"}
"""Each of ``METRICS`` in words."""


@dataclass(frozen=True)
class SolvedRule:
    """When a task counts as solved, over a set of finished episodes: those of the deterministic evaluation that
    decides 'solved' in training (play.py's episodes), or a training iteration's (the hint that triggers one)."""

    min_reward_per_step: float | None = None
    """Mean reward per step (episode return / episode length) at least this (None: any) ..."""
    min_time_limit_fraction: float = 0.0
    """... and at least this fraction of the episodes reached the time limit instead of failing ..."""
    full_episodes_only: bool = False
    """... where True: the mean reward per step over the episodes that ran the whole time limit (at least one must
    have)."""

    def __call__(self, summary: EpisodeSummary) -> bool:
        """Whether ``summary`` meets the rule."""
        per_step = summary.full_reward_per_step if self.full_episodes_only else summary.mean_reward_per_step
        if per_step is None or summary.time_limit_fraction is None:
            return False
        return all(met for *_, met in self.conditions(vars(summary)))

    def conditions(self, metrics: dict) -> list[tuple[str, float | None, float, bool]]:
        """Each of the rule's conditions over ``metrics`` (``EpisodeSummary``'s means by name, e.g. an evaluation's in
        a run's history): (the metric, its value, the minimum, whether it is met)."""
        minimums = []
        if self.min_reward_per_step is not None:
            key = "full_reward_per_step" if self.full_episodes_only else "mean_reward_per_step"
            minimums.append((key, self.min_reward_per_step))
        if self.min_time_limit_fraction:
            minimums.append(("time_limit_fraction", self.min_time_limit_fraction))
        return [(key, metrics.get(key), minimum, metrics.get(key) is not None and metrics[key] >= minimum)
                for key, minimum in minimums]

    def hopeless(self, failed: int, episodes: int) -> bool:
        """Whether ``failed`` of ``episodes`` episodes, ended before the time limit, already keep the rule from being
        met, whatever the others do (its time-limit fraction; a rule without one is never hopeless this way)."""
        return self.min_time_limit_fraction > 0 and (episodes - failed) / episodes < self.min_time_limit_fraction

    def episode_success(self, returns: Any, lengths: Any, reached_limit: Any) -> Any:
        """Per episode (tensors): it reached the time limit and, for a rule over full-length episodes, its reward per
        step (``returns / lengths``) meets the minimum."""
        if not self.full_episodes_only or self.min_reward_per_step is None:
            return reached_limit
        return reached_limit & (returns / lengths.clamp(min=1) >= self.min_reward_per_step)

    def describe(self) -> str:
        """The rule in words."""
        conditions = []
        if self.min_reward_per_step is not None:
            over = " over full-length episodes" if self.full_episodes_only else ""
            conditions.append(f"mean reward per step{over} >= {self.min_reward_per_step:g}")
        if self.min_time_limit_fraction:
            conditions.append(f">= {self.min_time_limit_fraction:.0%} of the episodes reach the time limit")
        return " and ".join(conditions) or "any"
