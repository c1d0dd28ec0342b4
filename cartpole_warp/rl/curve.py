"""The learning curve of a run (matplotlib's object API: no display, no global backend)."""

from __future__ import annotations

from pathlib import Path

from matplotlib.figure import Figure
from matplotlib.ticker import MaxNLocator

from ..files import atomic_write
from ..tasks import SolvedRule


def plot_learning_curve(path: Path, history: list[dict], solved: SolvedRule) -> Path:
    """PNG of the mean reward per step (of full-length episodes where the task's rule counts those) and the fraction
    of episodes that reached the time limit: the training episodes finished in each iteration as lines, the
    deterministic evaluations as dots, the thresholds of the task's ``solved`` rule as dashed lines; iterations
    counted from 1."""
    per_step = "full_reward_per_step" if solved.full_episodes_only else "mean_reward_per_step"
    figure = Figure(figsize=(8, 6), layout="constrained")
    top, bottom = figure.subplots(2, 1, sharex=True)
    for axes, key, threshold in ((top, per_step, solved.min_reward_per_step),
                                 (bottom, "time_limit_fraction", solved.min_time_limit_fraction or None)):
        trained = [h for h in history if h.get(key) is not None]
        axes.plot([h["iteration"] + 1 for h in trained], [h[key] for h in trained], color="tab:blue",
                  label="training episodes")
        evaluated = [h for h in history if (h.get("evaluation") or {}).get(key) is not None]
        axes.plot([h["iteration"] + 1 for h in evaluated], [h["evaluation"][key] for h in evaluated], "o",
                  color="tab:green", label="evaluation (deterministic policy)")
        if threshold is not None:
            axes.axhline(threshold, color="tab:red", linestyle="--", label=f"solved: >= {threshold:g}")
        axes.grid(alpha=0.3)
        if axes.get_legend_handles_labels()[0]:
            axes.legend(loc="lower right")
    top.set_ylabel("mean reward per step" + (" (full episodes)" if solved.full_episodes_only else ""))
    bottom.set_ylabel("episodes reaching the time limit")
    bottom.set_xlabel("iteration")
    bottom.xaxis.set_major_locator(MaxNLocator(integer=True))
    top.set_title("episodes per iteration")
    return atomic_write(path, lambda tmp: figure.savefig(tmp, format="png", dpi=100))
