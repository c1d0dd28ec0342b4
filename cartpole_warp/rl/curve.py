"""The learning curve of a run (matplotlib's object API: no display, no global backend)."""

from __future__ import annotations

from pathlib import Path

from matplotlib.figure import Figure
from matplotlib.ticker import MaxNLocator

from ..files import atomic_write
from ..tasks import SolvedRule


def plot_learning_curve(path: Path, history: list[dict], env_dt_s: float, max_episode_length: int | None,
                        solved: SolvedRule) -> Path:
    """PNG of the mean reward per step (of full-length episodes too, where the task's rule counts those) and the mean
    episode length (s) of the episodes finished in each iteration, with the thresholds of the task's ``solved`` rule
    as dashed lines; iterations counted from 1."""
    finished = [h for h in history if h["episodes"]]
    iterations = [h["iteration"] + 1 for h in finished]
    figure = Figure(figsize=(8, 6), layout="constrained")
    top, bottom = figure.subplots(2, 1, sharex=True)
    top.plot(iterations, [h["mean_reward_per_step"] for h in finished], color="tab:blue", label="finished episodes")
    if solved.full_episodes_only:
        full = [h for h in finished if h.get("full_reward_per_step") is not None]
        top.plot([h["iteration"] + 1 for h in full], [h["full_reward_per_step"] for h in full], color="tab:green",
                 label="full-length episodes")
    if solved.min_reward_per_step is not None:
        top.axhline(solved.min_reward_per_step, color="tab:red", linestyle="--",
                    label=f"solved: >= {solved.min_reward_per_step:g}")
    top.set_ylabel("mean reward per step")
    bottom.plot(iterations, [h["mean_episode_length"] * env_dt_s for h in finished], color="tab:blue")
    if max_episode_length is not None and solved.min_length_fraction:
        limit_s = max_episode_length * env_dt_s
        bottom.axhline(solved.min_length_fraction * limit_s, color="tab:red", linestyle="--",
                       label=f"solved: >= {solved.min_length_fraction:.0%} of the {limit_s:g} s limit")
    bottom.set_ylabel("mean episode length (s)")
    bottom.set_xlabel("iteration")
    bottom.xaxis.set_major_locator(MaxNLocator(integer=True))
    for axes in (top, bottom):
        axes.grid(alpha=0.3)
        if axes.get_legend_handles_labels()[0]:
            axes.legend(loc="lower right")
    top.set_title("finished episodes per iteration")
    return atomic_write(path, lambda tmp: figure.savefig(tmp, format="png", dpi=100))
