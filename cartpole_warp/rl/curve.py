"""The learning curve of a run (matplotlib's object API: no display, no global backend)."""

from __future__ import annotations

import textwrap
from pathlib import Path

from matplotlib.figure import Figure
from matplotlib.ticker import MaxNLocator

from ..evaluation.statistics import METRIC_LABELS
from ..settings.files import atomic_write
from ..tasks import Task


def curve_panels(task: Task) -> list[str]:
    """The ``EpisodeSummary`` means the curve draws, one panel each: the reward per step that the task's rule judges
    (of full-length episodes where it counts those), the fraction of episodes that reached the time limit where the
    rule or the play metric is that, and the task's play metric."""
    rule = task.solved
    panels = ["full_reward_per_step" if rule.full_episodes_only else "mean_reward_per_step"]
    if rule.min_time_limit_fraction or task.play_metric == "time_limit_fraction":
        panels.append("time_limit_fraction")
    return panels + [task.play_metric] * (task.play_metric not in panels)


def plot_learning_curve(path: Path, history: list[dict], task: Task, title: str) -> Path:
    """PNG of ``curve_panels``: the training episodes finished in each iteration as lines, the deterministic
    evaluations as dots, the thresholds of the task's solved rule as dashed lines, the legends beside the panels;
    iterations counted from 1; ``title`` names the run."""
    panels = curve_panels(task)
    thresholds = {"time_limit_fraction": task.solved.min_time_limit_fraction or None,
                  panels[0]: task.solved.min_reward_per_step}
    figure = Figure(figsize=(8, 6), layout="constrained")
    figure.suptitle(title)
    axes_list = figure.subplots(len(panels), 1, sharex=True, squeeze=False)[:, 0]
    for axes, key in zip(axes_list, panels):
        trained = [h for h in history if h.get(key) is not None]
        axes.plot([h["iteration"] + 1 for h in trained], [h[key] for h in trained], color="tab:blue",
                  label="training episodes")
        evaluated = [h for h in history if (h.get("evaluation") or {}).get(key) is not None]
        axes.plot([h["evaluation"].get("policy_iteration", h["iteration"]) + 1 for h in evaluated],
                  [h["evaluation"][key] for h in evaluated], "o",
                  color="tab:green", label="evaluation\n(deterministic policy)")
        if thresholds.get(key) is not None:
            axes.axhline(thresholds[key], color="tab:red", linestyle="--", label=f"solved: >= {thresholds[key]:g}")
        axes.grid(alpha=0.3)
        label = METRIC_LABELS[key] + (" (play metric)" if key == task.play_metric else "")
        axes.set_ylabel(textwrap.fill(label, 24))
        if axes.get_legend_handles_labels()[0]:
            axes.legend(loc="upper left", bbox_to_anchor=(1.01, 1.0), fontsize="small")
    axes_list[-1].set_xlabel("iteration")
    axes_list[-1].xaxis.set_major_locator(MaxNLocator(integer=True))
    return atomic_write(path, lambda tmp: figure.savefig(tmp, format="png", dpi=100))
