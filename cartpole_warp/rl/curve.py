"""The learning curve of a run (matplotlib's object API: no display, no global backend)."""

from __future__ import annotations

from pathlib import Path

from matplotlib.figure import Figure
from matplotlib.ticker import MaxNLocator

from .metrics import SOLVED_LENGTH_FRACTION, SOLVED_REWARD_PER_STEP
from .runs import atomic_write


def plot_learning_curve(path: Path, history: list[dict], env_dt_s: float, max_episode_length: int | None) -> Path:
    """PNG of the mean reward per step and the mean episode length (s) of the episodes finished in each iteration,
    with the thresholds of "solved" as dashed lines; iterations counted from 1."""
    iterations = [h["iteration"] + 1 for h in history if h["episodes"]]
    reward = [h["mean_reward_per_step"] for h in history if h["episodes"]]
    length_s = [h["mean_episode_length"] * env_dt_s for h in history if h["episodes"]]
    figure = Figure(figsize=(8, 6), layout="constrained")
    top, bottom = figure.subplots(2, 1, sharex=True)
    top.plot(iterations, reward, color="tab:blue")
    top.axhline(SOLVED_REWARD_PER_STEP, color="tab:red", linestyle="--", label=f"solved: >= {SOLVED_REWARD_PER_STEP}")
    top.set_ylabel("mean reward per step")
    bottom.plot(iterations, length_s, color="tab:blue")
    if max_episode_length is not None:
        limit_s = max_episode_length * env_dt_s
        bottom.axhline(SOLVED_LENGTH_FRACTION * limit_s, color="tab:red", linestyle="--",
                       label=f"solved: >= {SOLVED_LENGTH_FRACTION:.0%} of the {limit_s:g} s limit")
    bottom.set_ylabel("mean episode length (s)")
    bottom.set_xlabel("iteration")
    bottom.xaxis.set_major_locator(MaxNLocator(integer=True))
    for axes in (top, bottom):
        axes.grid(alpha=0.3)
        if axes.get_legend_handles_labels()[0]:
            axes.legend(loc="lower right")
    top.set_title("finished episodes per iteration")
    return atomic_write(path, lambda tmp: figure.savefig(tmp, format="png", dpi=100))
