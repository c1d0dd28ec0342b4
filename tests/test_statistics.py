"""Episode statistics (``statistics.py``) and the tasks' solved rules over them."""

import math

import torch

from cartpole_warp import tasks
from cartpole_warp.evaluation.statistics import EpisodeStats, EpisodeSummary


def summary(time_limit_fraction, per_step, full_per_step=None):
    return EpisodeSummary(1, None, None, per_step, time_limit_fraction, int(full_per_step is not None), full_per_step)


def test_the_balance_task_is_solved_by_time_limit_fraction_and_reward_per_step():
    solved = tasks.get("cartpole-balance").solved
    assert solved(summary(0.95, 0.9))
    assert not solved(summary(0.949, 0.99))
    assert not solved(summary(1.0, 0.89))
    assert not solved(EpisodeSummary(0, None, None, None, None))


def test_the_swingup_is_solved_by_the_reward_per_step_of_full_episodes():
    solved = tasks.get("cartpole-swingup").solved
    assert solved(summary(0.1, 0.1, full_per_step=0.8)), "short first episodes do not count against it"
    assert not solved(summary(1.0, 0.95)), "no full episode: not solved"
    assert not solved(summary(1.0, 0.9, full_per_step=0.79))


def test_episode_stats_average_the_ended_episodes_and_the_full_ones():
    stats = EpisodeStats("cpu", max_episode_length=10)
    ended = torch.tensor([True, True, False])
    stats.add(ended, torch.tensor([10.0, -2.0, 99.0]), torch.tensor([10, 1, 10]), torch.tensor([True, False, True]))
    summary = stats.pop()
    assert summary.episodes == 2 and summary.mean_return == 4.0 and summary.mean_episode_length == 5.5
    assert math.isclose(summary.mean_reward_per_step, (1.0 - 2.0) / 2) and summary.time_limit_fraction == 0.5
    assert summary.full_episodes == 1 and summary.full_reward_per_step == 1.0
    assert stats.summary().episodes == 0 and stats.summary().mean_return is None
